"""What the viewer saves: the camera path through the keyframes a user placed (a file `simplenerf render-video`
renders with `--trajectory`), and screenshots of the current render. Files go to the viewer's output folder
(`<run>/viewer/` by default) and are also sent to the browser as downloads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import viser.transforms as vtf

from simplenerf.viewer.camera import ViewerCamera
from simplenerf.viz.camera_path import CameraPath, write_camera_path
from simplenerf.viz.pictures import write_png


def interpolate_path(keyframes: list[ViewerCamera], frames_per_segment: int) -> np.ndarray:
    """Poses c2w [N, 3, 4] through `keyframes`: between two consecutive keyframes `frames_per_segment` poses with the
    centre moving linearly and the rotation by spherical interpolation (slerp), then the last keyframe itself;
    N = (K - 1) * frames_per_segment + 1 for K keyframes (one keyframe: N = 1)."""
    if not keyframes:
        raise ValueError("a camera path needs at least one keyframe")
    if frames_per_segment < 1:
        raise ValueError(f"frames_per_segment must be at least 1, got {frames_per_segment}")
    poses = []
    for a, b in zip(keyframes[:-1], keyframes[1:], strict=True):
        ra, rb = vtf.SO3.from_matrix(a.c2w[:, :3]), vtf.SO3.from_matrix(b.c2w[:, :3])
        delta = (ra.inverse() @ rb).log()  # the rotation from a to b as an axis-angle vector
        for i in range(frames_per_segment):
            s = i / frames_per_segment
            rotation = (ra @ vtf.SO3.exp(s * delta)).as_matrix()
            centre = (1 - s) * a.centre + s * b.centre
            poses.append(np.concatenate([rotation, centre[:, None]], axis=1))
    poses.append(keyframes[-1].c2w)
    return np.stack(poses)


def camera_path(keyframes: list[ViewerCamera], frames_per_segment: int, max_side: int, fps: float, fov_y: float,
                aspect: float) -> CameraPath:
    """The path through `keyframes` for frames of vertical field of view `fov_y` (radians) and `aspect` (width /
    height, the larger side `max_side`): the train views' in the viewer, as `simplenerf render-video` builds the NDC of
    its rays from the frames' camera (that of the data only with the train views' field of view and aspect)."""
    width, height = ViewerCamera(np.eye(3, 4), fov_y, aspect).image_size(max_side)
    return CameraPath(torch.from_numpy(interpolate_path(keyframes, frames_per_segment)), width, height, fov_y, fps)


def next_free(folder: Path, stem: str, suffix: str) -> Path:
    """`<folder>/<stem>_<n><suffix>` with the smallest n >= 1 not taken (exports never overwrite one another)."""
    n = 1
    while (folder / f"{stem}_{n}{suffix}").exists():
        n += 1
    return folder / f"{stem}_{n}{suffix}"


def save_camera_path(folder: Path, path: CameraPath) -> Path:
    """Writes the path as `camera_path_<n>.json` in `folder`; returns the file."""
    folder.mkdir(parents=True, exist_ok=True)
    return write_camera_path(next_free(folder, "camera_path", ".json"), path)


def save_screenshot(folder: Path, picture: np.ndarray) -> Path:
    """Writes an 8-bit RGB picture [H, W, 3] as `screenshot_<n>.png` in `folder`; returns the file."""
    folder.mkdir(parents=True, exist_ok=True)
    out = next_free(folder, "screenshot", ".png")
    write_png(out, picture)
    return out
