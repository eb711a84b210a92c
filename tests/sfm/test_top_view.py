"""The top view of an SfM result: the scene above the cameras, left to the left, each point in its own colour."""

from __future__ import annotations

import numpy as np
import pytest

from simplenerf.sfm.top_view import top_view_picture


def test_points_in_front_are_above_the_cameras_and_keep_their_colour() -> None:
    c2w = np.concatenate([np.broadcast_to(np.eye(3), (2, 3, 3)), np.array([[-1.0, 0, 0], [1, 0, 0]])[:, :, None]],
                         axis=2)  # two cameras 2 apart, looking along -z (OpenGL)
    points = np.array([[-1.0, 0.0, -5.0], [1.0, 0.0, -5.0]])
    colours = np.array([[0, 200, 0], [0, 0, 200]], dtype=np.uint8)
    picture = top_view_picture(c2w, points, colours, ["0", "1"], title="t", size=400)
    assert picture.shape == (400, 400, 3) and picture.dtype == np.uint8
    green = np.argwhere((picture == [0, 200, 0]).all(-1))
    blue = np.argwhere((picture == [0, 0, 200]).all(-1))
    red = np.argwhere((picture[..., 0] > 150) & (picture[..., 1] < 100) & (picture[..., 2] < 100))
    assert len(green) and len(blue) and len(red)
    assert green[:, 1].mean() < blue[:, 1].mean()  # the point at x = -1 is left of the one at x = +1
    assert green[:, 0].mean() < red[:, 0].min()  # both points (5 in front) are above every camera
    # Same depth, so the same row; the two cameras' wedges sit symmetrically about the middle.
    assert green[:, 0].mean() == pytest.approx(blue[:, 0].mean(), abs=0.5)
    assert (red[:, 1].min() + red[:, 1].max()) / 2 == pytest.approx(200, abs=3)


def test_no_points_and_bad_inputs() -> None:
    c2w = np.concatenate([np.eye(3), np.zeros((3, 1))], axis=1)[None]
    assert top_view_picture(c2w, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), ["0"]).shape == (800, 800, 3)
    with pytest.raises(ValueError, match="one label per camera"):
        top_view_picture(c2w, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), [])
