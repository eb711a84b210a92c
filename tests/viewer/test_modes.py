from types import SimpleNamespace

import cv2
import numpy as np
import torch

from simplenerf.geometry.views import Views
from simplenerf.viewer.modes import depth_picture, mask_overlay, render_modes, sample_mask


def test_render_modes_of_a_model_with_two_augmentations_and_cfc():
    model = SimpleNamespace(augmentations=[SimpleNamespace(name="points", mask=object()),
                                           SimpleNamespace(name="views", mask=object())], coarse_fine_mask=object())
    assert [m.label for m in render_modes(model)] == [
        "RGB", "depth", "accumulation", "coarse | fine depth", "depth: points (augmented)", "depth: views (augmented)",
        "mask: points", "mask: views", "mask: cfc"]
    plain = SimpleNamespace(augmentations=[], coarse_fine_mask=None)  # DS-NeRF: no augmentation, no mask
    assert [m.label for m in render_modes(plain)] == ["RGB", "depth", "accumulation", "coarse | fine depth"]


def test_depth_colours_use_the_fixed_range():
    picture = depth_picture(np.array([[1.0, 4.0, 0.5, 100.0]]), (1.0, 4.0))
    turbo = cv2.cvtColor(cv2.applyColorMap(np.array([[255, 0]], np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    assert np.array_equal(picture[0, :2], turbo[0])  # closest: top of the map, farthest: bottom
    assert np.array_equal(picture[0, 2:], turbo[0])  # outside the range: clipped to its ends


def test_mask_overlay_colours():
    rgb = np.full((1, 4, 3), 0.5)
    out = mask_overlay(rgb, np.array([[1, -1, 0, 1]]), np.array([[True, True, True, False]]))
    expected = [[0.2 + 0.6 * 0.1, 0.2 + 0.6 * 0.85, 0.2 + 0.6 * 0.2], [0.2 + 0.6 * 0.9, 0.2 + 0.6 * 0.1,
                0.2 + 0.6 * 0.8], [0.5, 0.5, 0.5], [0.15, 0.15, 0.15]]
    assert np.array_equal(out[0], np.round(np.array(expected) * 255).astype(np.uint8))


def test_sample_mask_reads_the_pixel_a_point_projects_to():
    k = torch.tensor([[[10.0, 0.0, 2.0], [0.0, 10.0, 1.5], [0.0, 0.0, 1.0]]])
    views = Views(torch.zeros(1, 3, 4, 3), k, torch.eye(3, 4)[None], ["a"])
    mask = torch.tensor([[1, 0, -1, 1], [0, 0, 0, 0], [-1, 1, 1, 0]])
    # pixel (u, v) at depth z is ((u - cx) z / f, -(v - cy) z / f, -z) (OpenGL camera at the origin)
    points = torch.tensor([[(2 - 2.0) * 2 / 10, 0.0, -2.0], [(0 - 2.0) * 3 / 10, -(2 - 1.5) * 3 / 10, -3.0],
                           [5.0, 0.0, -1.0], [0.0, 0.0, 2.0]])  # (2, 1.5 -> 2), (0, 2), outside, behind
    values, seen = sample_mask(mask, views, 0, points)
    assert seen.tolist() == [True, True, False, False]
    assert values.tolist() == [1, -1, 0, 0]
