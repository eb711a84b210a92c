"""Camera poses: LLFF's `poses_bounds.npy` rows and this package's OpenGL camera-to-world, the average pose, recentring.

Poses follow `geometry.rays`: c2w [..., 3, 4] in OpenGL axes (columns right, up, back; the camera looks along -z).
LLFF's rows (its `imgs2poses` / `pose_utils.py`) hold a 3x5 matrix [down, right, back, centre, (height, width, focal)]
flattened row-major, then near and far.
"""

from __future__ import annotations

import numpy as np


def poses_to_opengl(poses_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Splits LLFF's [N, 17] rows into c2w [N, 3, 4] (OpenGL axes), hwf [N, 3] and bounds [N, 2].

    LLFF stores the rotation columns as [down, right, back]; OpenGL's are [right, up, back].
    """
    mats = poses_bounds[:, :15].reshape(-1, 3, 5)
    down, right, back, centre = mats[:, :, 0], mats[:, :, 1], mats[:, :, 2], mats[:, :, 3]
    c2w = np.stack([right, -down, back, centre], axis=-1)
    return c2w, mats[:, :, 4], poses_bounds[:, 15:17]


def normalize(v: np.ndarray) -> np.ndarray:
    """Unit vectors [..., 3] along v [..., 3]."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def average_pose(c2w: np.ndarray) -> np.ndarray:
    """The mean camera [3, 4]: mean centre, mean viewing axis, mean up vector (orthonormalised)."""
    centre = c2w[:, :, 3].mean(0)
    back = normalize(c2w[:, :, 2].sum(0))
    right = normalize(np.cross(c2w[:, :, 1].sum(0), back))
    up = np.cross(back, right)
    return np.stack([right, up, back, centre], axis=-1)


def recenter(c2w: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Expresses poses [N, 3, 4] in the frame of `reference` [3, 4]."""
    to_h = np.array([[0.0, 0.0, 0.0, 1.0]])
    ref_inv = np.linalg.inv(np.concatenate([reference, to_h]))
    return np.stack([(ref_inv @ np.concatenate([p, to_h]))[:3] for p in c2w])


def to_poses_bounds(c2w: np.ndarray, hwf: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """LLFF's [N, 17] rows from c2w [N, 3, 4] (OpenGL), hwf [N, 3] and bounds [N, 2]: the inverse of
    `poses_to_opengl` (rotation columns [down, right, back] = [-up, right, back])."""
    c2w = np.asarray(c2w, dtype=np.float64)
    mats = np.concatenate([-c2w[:, :, 1:2], c2w[:, :, 0:1], c2w[:, :, 2:4], np.asarray(hwf, np.float64)[:, :, None]],
                          axis=2)
    return np.concatenate([mats.reshape(len(c2w), 15), np.asarray(bounds, np.float64)], axis=1)
