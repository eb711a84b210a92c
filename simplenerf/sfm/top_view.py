"""A picture of a structure-from-motion result to check at a glance: cameras and 3D points seen from above."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

_CAMERA_COLOUR = (220, 30, 30)
_BACKGROUND = 240


def top_view_picture(
    c2w: np.ndarray,
    points: np.ndarray,
    colours: np.ndarray,
    labels: Sequence[str],
    title: str = "",
    size: int = 800,
) -> np.ndarray:
    """Cameras and points projected on the ground plane of the average camera: 8-bit RGB [size, size, 3].

    The horizontal axis is the average camera's right, the vertical axis its viewing direction (the scene is above
    the cameras); each camera is a red wedge opening where it looks, labelled, each point a dot of its own colour.
    The view is fitted to all cameras and the 2nd-98th percentiles of the points, so a few stray points cannot
    shrink the rest to a speck.

    Args:
        c2w: [N, 3, 4] camera-to-world, OpenGL axes (right, up, back), N >= 1.
        points: [P, 3] world points (P may be 0).
        colours: [P, 3] uint8 RGB colour of each point.
        labels: N short texts drawn next to the cameras (e.g. frame indices).
        title: a line of text at the top.
        size: width and height of the picture in pixels.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if c2w.ndim != 3 or c2w.shape[1:] != (3, 4) or len(c2w) == 0:
        raise ValueError(f"c2w must be [N, 3, 4] with N >= 1, got {c2w.shape}")
    if len(labels) != len(c2w) or len(colours) != len(points):
        raise ValueError("need one label per camera and one colour per point")
    centre = c2w[:, :, 3].mean(0)
    back = c2w[:, :, 2].sum(0)
    back /= max(np.linalg.norm(back), 1e-12)
    right = np.cross(c2w[:, :, 1].sum(0), back)
    right /= max(np.linalg.norm(right), 1e-12)
    # Ground-plane coordinates: (right, forward) of the average camera.
    axes = np.stack([right, -back], axis=1)  # [3, 2]
    cams_2d = (c2w[:, :, 3] - centre) @ axes
    points_2d = (points - centre) @ axes
    extent = cams_2d
    if len(points_2d):
        lo, hi = np.percentile(points_2d, [2, 98], axis=0)
        extent = np.concatenate([cams_2d, lo[None], hi[None]])
    lo, hi = extent.min(0), extent.max(0)
    span = max(float((hi - lo).max()), 1e-9)
    margin, header = 0.06 * size, 30
    scale = (size - 2 * margin - header) / span
    mid = (lo + hi) / 2

    def to_pixels(xy: np.ndarray) -> np.ndarray:
        u = size / 2 + (xy[:, 0] - mid[0]) * scale
        v = (size + header) / 2 - (xy[:, 1] - mid[1]) * scale
        return np.stack([u, v], axis=1)

    picture = np.full((size, size, 3), _BACKGROUND, dtype=np.uint8)
    if len(points_2d):
        pix = np.round(to_pixels(points_2d)).astype(np.int64)
        inside = (pix[:, 0] >= 0) & (pix[:, 0] < size) & (pix[:, 1] >= header) & (pix[:, 1] < size)
        for (u, v), colour in zip(pix[inside], np.asarray(colours)[inside], strict=True):
            cv2.circle(picture, (int(u), int(v)), 1, tuple(int(c) for c in colour), -1)
    cams_pix = to_pixels(cams_2d)
    # Wedges as long as the typical spacing of the cameras on screen (kept readable), labels where they do not overlap.
    gaps = np.linalg.norm(cams_pix[:, None] - cams_pix[None], axis=-1) + np.eye(len(cams_pix)) * size
    wedge = float(np.clip(0.8 * np.median(gaps.min(1)), 8.0, 0.04 * size)) if len(cams_pix) > 1 else 0.04 * size
    forward_2d = (-c2w[:, :, 2]) @ axes
    right_2d = c2w[:, :, 0] @ axes
    labelled: list[np.ndarray] = []
    for pix, fwd, rgt, label in zip(cams_pix, forward_2d, right_2d, labels, strict=True):
        # Screen directions: v grows downwards, so a world direction (x, y) is (x, -y) on screen.
        f = np.array([fwd[0], -fwd[1]]) / max(np.linalg.norm(fwd), 1e-12)
        r = np.array([rgt[0], -rgt[1]]) / max(np.linalg.norm(rgt), 1e-12)
        corners = [pix, pix + wedge * (f + 0.5 * r), pix + wedge * (f - 0.5 * r)]
        cv2.polylines(picture, [np.round(corners).astype(np.int32)], True, _CAMERA_COLOUR, 1, cv2.LINE_AA)
        if all(np.linalg.norm(pix - other) > 14 for other in labelled):
            labelled.append(pix)
            cv2.putText(picture, label, (int(pix[0]) - 4, int(pix[1]) + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                        _CAMERA_COLOUR, 1, cv2.LINE_AA)
    cv2.putText(picture, title, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return picture
