"""Camera paths for videos: the LLFF spiral, RealEstate-10K's recorded trajectory and a saved path (the viewer's).

Poses follow `geometry.rays`: c2w [..., 3, 4] in OpenGL axes (columns right, up, back; the camera looks along -z),
positions in scene units (after the data module's scaling and recentring).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from simplenerf.data.llff import average_pose
from simplenerf.data.scene import Scene
from simplenerf.errors import DataError
from simplenerf.geometry.views import Views

TrajectoryKind = Literal["spiral", "recorded"]


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spiral_focus_depth(bounds: np.ndarray, dt: float = 0.75) -> float:
    """The depth the spiral's cameras look at: 1 / ((1 - dt) / close + dt / inf), close = 0.9 * min near and
    inf = 5 * max far of bounds [V, 2] (LLFF's render path: a weighted harmonic mean, so mostly the near content)."""
    close, inf = 0.9 * float(bounds[:, 0].min()), 5.0 * float(bounds[:, 1].max())
    return 1.0 / ((1.0 - dt) / close + dt / inf)


def llff_spiral(
    c2w: torch.Tensor, bounds: np.ndarray | torch.Tensor, n_frames: int = 120, n_rotations: float = 2,
    zrate: float = 0.5,
) -> torch.Tensor:
    """The standard LLFF / NeRF video path, in this package's OpenGL axes, fitted to a set of camera poses.

    The camera centre moves on an ellipse-like spiral around the average pose (`data.llff.average_pose`): in that
    pose's frame, offset(theta) = [r_x cos theta, -r_y sin theta, -r_z sin(zrate theta)] for
    theta = 2 pi n_rotations i / n_frames, i = 0 .. n_frames - 1 (the start frame is not repeated at the end), with
    radii r = the 90th percentile of |camera position - average centre| per axis of that frame. Every camera looks at
    the point `spiral_focus_depth(bounds)` in front of the average pose (along its -z) and keeps the mean up vector as
    up. The authors' release fits the path to all frames of the scene (`scene_trajectory`).

    Args:
        c2w: [V, 3, 4] the camera poses the path is fitted to.
        bounds: [V, 2] near/far depth of each of those views, scene units.
        n_frames: number of poses.
        n_rotations: turns around the centre.
        zrate: the forward/backward motion turns `zrate` times per turn in the image plane.

    Returns:
        [n_frames, 3, 4] poses, dtype and device of c2w.
    """
    if c2w.ndim != 3 or c2w.shape[1:] != (3, 4):
        raise ValueError(f"c2w must be [V, 3, 4], got {tuple(c2w.shape)}")
    b = bounds.detach().cpu().double().numpy() if isinstance(bounds, torch.Tensor) else np.asarray(bounds, np.float64)
    if b.shape != (c2w.shape[0], 2) or not (b > 0).all():
        raise ValueError(f"bounds must be [{c2w.shape[0]}, 2] positive near/far depths, got {b.shape}")
    if n_frames < 1:
        raise ValueError(f"n_frames must be at least 1, got {n_frames}")

    poses = c2w.detach().cpu().double().numpy()
    centre_pose = average_pose(poses)
    rotation, centre = centre_pose[:, :3], centre_pose[:, 3]
    up = _normalize(poses[:, :, 1].sum(0))
    offsets = (poses[:, :, 3] - centre) @ rotation  # [V, 3] positions in the average pose's frame
    radii = np.percentile(np.abs(offsets), 90, axis=0)

    theta = np.linspace(0.0, 2.0 * math.pi * n_rotations, n_frames, endpoint=False)
    local = np.stack([np.cos(theta), -np.sin(theta), -np.sin(zrate * theta)], axis=-1) * radii  # [N, 3]
    positions = centre + local @ rotation.T
    focus = centre - spiral_focus_depth(b) * rotation[:, 2]  # on the average viewing axis (-z)
    back = _normalize(positions - focus)  # the camera looks along -back, i.e. at the focus point
    right = _normalize(np.cross(up, back))
    cam_up = np.cross(back, right)
    path = np.stack([right, cam_up, back, positions], axis=-1)  # [N, 3, 4]
    return torch.from_numpy(path).to(dtype=c2w.dtype, device=c2w.device)


def recorded_trajectory(views: Views) -> torch.Tensor:
    """The camera path of the frames themselves, in frame order (RealEstate-10K clips): c2w [V, 3, 4]."""
    return views.c2w.clone()


def scene_trajectory(
    scene: Scene, kind: TrajectoryKind, n_frames: int = 120, n_rotations: float = 2
) -> torch.Tensor:
    """The video path of a scene: the spiral fitted to ALL its frames' poses and bounds, or the recorded path of all
    its frames (n_frames and n_rotations are then unused). Returns c2w [N, 3, 4].

    The spiral follows the authors' release, which fits it to every frame of the scene, train and test: with 2 train
    views the 90th-percentile radii of the train poses alone are those of the two cameras, so the path would shrink
    to (nearly) a line between them. A scene of one's own photos without other frames has only its train views,
    which are then all there is to fit to.
    """
    if kind == "spiral":
        return llff_spiral(scene.views.c2w, scene.bounds, n_frames, n_rotations)
    if kind == "recorded":
        return recorded_trajectory(scene.views)
    raise ValueError(f"unknown trajectory {kind!r}: expected 'spiral' or 'recorded'")


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
    """Writes `camera_path` as JSON (what tools/render_video.py --trajectory reads); returns the path."""
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
