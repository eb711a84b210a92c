"""A camera path saved as a file: what the viewer exports and `simplenerf render-video --trajectory` renders."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from simplenerf.errors import DataError

CAMERA_PATH_FORMAT = "simplenerf camera path"


@dataclass
class CameraPath:
    """A camera path saved as a file (the viewer's export): poses, one pinhole camera, the frame rate."""

    c2w: torch.Tensor  # [N, 3, 4] OpenGL axes, scene units
    width: int
    height: int
    fov_y: float  # vertical field of view, radians (square pixels, principal point at the centre)
    fps: float

    @property
    def intrinsics(self) -> torch.Tensor:
        """[3, 3] of a width x height frame."""
        focal = 0.5 * self.height / math.tan(0.5 * self.fov_y)
        return torch.tensor([[focal, 0.0, self.width / 2.0], [0.0, focal, self.height / 2.0], [0.0, 0.0, 1.0]],
                            dtype=self.c2w.dtype)


def write_camera_path(path: str | Path, camera_path: CameraPath) -> Path:
    """Writes `camera_path` as JSON (what `simplenerf render-video --trajectory` reads); returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {"format": CAMERA_PATH_FORMAT, "version": 1, "axes": "c2w [3, 4]: OpenGL (right, up, back), scene units",
            "width": camera_path.width, "height": camera_path.height,
            "fov_y_degrees": math.degrees(camera_path.fov_y), "fps": camera_path.fps,
            "c2w": camera_path.c2w.detach().cpu().double().tolist()}
    out.write_text(json.dumps(data, indent=1))
    return out


def read_camera_path(path: str | Path) -> CameraPath:
    """The camera path of a file written by `write_camera_path`; DataError naming the file and what is wrong."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"cannot read camera path {path}: {e}") from None
    if not isinstance(data, dict) or data.get("format") != CAMERA_PATH_FORMAT:
        raise DataError(f"{path} is not a camera path (export one from `simplenerf view`)")
    try:
        c2w = torch.tensor(data["c2w"], dtype=torch.float64)
        width, height, fps = int(data["width"]), int(data["height"]), float(data["fps"])
        fov_y = math.radians(float(data["fov_y_degrees"]))
    except (KeyError, TypeError, ValueError) as e:
        raise DataError(f"camera path {path} is incomplete or malformed ({type(e).__name__}: {e})") from None
    if c2w.ndim != 3 or c2w.shape[1:] != (3, 4) or len(c2w) == 0 or min(width, height) < 1 or fps <= 0:
        raise DataError(f"camera path {path}: expected c2w [N >= 1, 3, 4], a positive size and fps, got "
                        f"{tuple(c2w.shape)}, {width}x{height}, {fps}")
    return CameraPath(c2w, width, height, fov_y, fps)
