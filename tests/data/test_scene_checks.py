"""A scene's files are checked before any training: each bad case stops with one DataError naming the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from simplenerf.data.llff import check_scene, list_images, load_llff_scene
from simplenerf.data.realestate import read_camera_file
from simplenerf.errors import DataError


@pytest.fixture
def scene(synthetic_scene, tmp_path) -> Path:
    return Path(shutil.copytree(synthetic_scene, tmp_path / "scene"))


def test_an_image_of_another_size_is_named_with_its_size(scene):
    odd = scene / "images" / "007.png"
    cv2.imwrite(str(odd), np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(DataError) as e:
        load_llff_scene(scene, factor=1, n_views=2)
    assert str(e.value) == f"{odd} is 32x24 but 000.png is 64x48: all images must have the same size"


def test_names_that_sort_differently_as_numbers_stop(tmp_path):
    for i in (1, 2, 10):
        (tmp_path / f"img{i}.png").write_bytes(b"")
    with pytest.raises(DataError) as e:
        list_images(tmp_path)
    assert str(e.value) == (
        f"{tmp_path}: image names sort differently as text and by number (as text img10.png comes before img2.png), "
        "so which pose of poses_bounds.npy belongs to which image is ambiguous; rename them with zero-padded numbers "
        "(e.g. img002.png)"
    )
    (tmp_path / "img10.png").rename(tmp_path / "img3.png")
    assert [p.name for p in list_images(tmp_path)] == ["img1.png", "img2.png", "img3.png"]


@pytest.mark.parametrize(
    "column,value,message",
    [
        (15, 0.0, "has near bound 0 and far bound {far:g}; they must be 0 < near < far"),
        (16, 0.5, "has near bound {near:g} and far bound 0.5; they must be 0 < near < far"),
        (7, np.nan, "has a non-finite value: "),
        (16, np.inf, "has a non-finite value: "),
        (14, 0.0, "has height, width, focal "),
    ],
)
def test_bad_poses_bounds_name_the_file_and_the_frame(scene, column, value, message):
    path = scene / "poses_bounds.npy"
    poses_bounds = np.load(path)
    near, far = poses_bounds[3, 15:17]
    poses_bounds[3, column] = value
    np.save(path, poses_bounds)
    with pytest.raises(DataError) as e:
        check_scene(scene, factor=1)
    assert str(e.value).startswith(f"{path}: frame 3 (003.png) " + message.format(near=near, far=far))


def test_a_non_finite_camera_line_is_named(tmp_path):
    path = tmp_path / "clip.txt"
    good = "1000 0.5 0.9 0.5 0.5 0 0 1 0 0 0 0 1 0 0 0 0 1 0"
    path.write_text(f"https://example.invalid/video\n{good}\n{good.replace('1000', '2000', 1).replace('0.9', 'nan')}\n")
    with pytest.raises(DataError) as e:
        read_camera_file(path)
    assert str(e.value) == f"{path} line 3 (frame 2000): the camera has a non-finite value"
