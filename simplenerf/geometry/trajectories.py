"""Camera paths for videos: the LLFF spiral (the authors' release, LLFF's render path) and RealEstate-10K's recorded
trajectory.

Poses follow `geometry.rays`: c2w [..., 3, 4] in OpenGL axes (columns right, up, back; the camera looks along -z),
positions in scene units (after the data module's scaling and recentring).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch

from simplenerf.geometry.poses import average_pose, normalize
from simplenerf.geometry.views import Views

TrajectoryKind = Literal["spiral", "recorded"]


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

    The camera centre moves on an ellipse-like spiral around the average pose (`geometry.poses.average_pose`): in that
    pose's frame, offset(theta) = [r_x cos theta, -r_y sin theta, -r_z sin(zrate theta)] for
    theta = 2 pi n_rotations i / n_frames, i = 0 .. n_frames - 1 (the start frame is not repeated at the end), with
    radii r = the 90th percentile of |camera position - average centre| per axis of that frame. Every camera looks at
    the point `spiral_focus_depth(bounds)` in front of the average pose (along its -z) and keeps the mean up vector as
    up. The authors' release fits the path to all frames of the scene (`data.scene.Scene.trajectory`).

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
    up = normalize(poses[:, :, 1].sum(0))
    offsets = (poses[:, :, 3] - centre) @ rotation  # [V, 3] positions in the average pose's frame
    radii = np.percentile(np.abs(offsets), 90, axis=0)

    theta = np.linspace(0.0, 2.0 * math.pi * n_rotations, n_frames, endpoint=False)
    local = np.stack([np.cos(theta), -np.sin(theta), -np.sin(zrate * theta)], axis=-1) * radii  # [N, 3]
    positions = centre + local @ rotation.T
    focus = centre - spiral_focus_depth(b) * rotation[:, 2]  # on the average viewing axis (-z)
    back = normalize(positions - focus)  # the camera looks along -back, i.e. at the focus point
    right = normalize(np.cross(up, back))
    cam_up = np.cross(back, right)
    path = np.stack([right, cam_up, back, positions], axis=-1)  # [N, 3, 4]
    return torch.from_numpy(path).to(dtype=c2w.dtype, device=c2w.device)


def recorded_trajectory(views: Views) -> torch.Tensor:
    """The camera path of the frames themselves, in frame order (RealEstate-10K clips): c2w [V, 3, 4]."""
    return views.c2w.clone()
