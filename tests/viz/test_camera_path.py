"""Camera path files (simplenerf.viz.camera_path): what the viewer exports and `simplenerf render-video` reads."""

from __future__ import annotations

import json
import math

import pytest
import torch

from simplenerf.errors import DataError
from simplenerf.viz.camera_path import CameraPath, read_camera_path, write_camera_path


def test_camera_path_file_round_trip_and_bad_files(tmp_path):
    c2w = torch.arange(24, dtype=torch.float64).reshape(2, 3, 4) / 7
    out = write_camera_path(tmp_path / "a" / "path.json", CameraPath(c2w, 64, 48, math.radians(60.0), 24.0))
    back = read_camera_path(out)
    assert torch.equal(back.c2w, c2w) and (back.width, back.height, back.fps) == (64, 48, 24.0)
    assert back.fov_y == pytest.approx(math.radians(60.0))
    focal = 24.0 / math.tan(math.radians(30.0))
    assert torch.allclose(back.intrinsics, torch.tensor([[focal, 0, 32.0], [0, focal, 24.0], [0, 0, 1]],
                                                        dtype=torch.float64))
    (tmp_path / "other.json").write_text(json.dumps({"frames": []}))
    with pytest.raises(DataError, match=r"other.json is not a camera path \(export one from `simplenerf view`\)"):
        read_camera_path(tmp_path / "other.json")
    data = json.loads(out.read_text())
    data["c2w"] = [[1.0, 2.0]]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(DataError, match=r"expected c2w \[N >= 1, 3, 4\].*got \(1, 2\)"):
        read_camera_path(tmp_path / "bad.json")
