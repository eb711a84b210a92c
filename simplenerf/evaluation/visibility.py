"""Visibility masks of test views (SPEC 7): the test pixels whose surface the train views saw, by reference depth.

The paper evaluates masked scores over the pixels that at least two train views saw. Whether a train view saw a test
pixel is decided by forward warping (as in the paper's protocol, not by backward projection):

1. Every pixel of the train view is lifted to 3D with its reference depth: point = o + z d with the un-normalised ray
   direction of `rays.pixel_rays`, so z is the camera z-depth (the conventions of `simplenerf.geometry.rays`).
2. The points are projected into the test camera (`rays.project`) and rounded to the nearest pixel; points behind the
   camera (z <= 0) or outside the image are dropped. Where several points land on one pixel the nearest wins
   (a z-buffer), which is what makes occluded surfaces drop out.
3. A test pixel is seen by that train view if |warped depth - test reference depth| < 0.05 x the train view's
   maximum depth; it is visible if seen by at least `min_views` (2) train views. With 2 train views that means both.

Depth maps are [H, W] camera z-depths in scene units. Depths that are not finite or not positive are never warped and
never match, so a pixel without reference depth is never visible.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tqdm import tqdm

from simplenerf.data.datasets import Views
from simplenerf.geometry.rays import pixel_grid, pixel_rays, project

RELATIVE_TOLERANCE = 0.05
"""A train view sees a test pixel if the depths agree within this fraction of the train view's maximum depth."""

MIN_VIEWS = 2
"""A test pixel is evaluated (visible) if at least this many train views see it."""


def _valid(depth: torch.Tensor) -> torch.Tensor:
    return torch.isfinite(depth) & (depth > 0)


def forward_warp_depth(
    depth: torch.Tensor,
    intrinsics: torch.Tensor,
    c2w: torch.Tensor,
    target_intrinsics: torch.Tensor,
    target_c2w: torch.Tensor,
    height: int,
    width: int,
) -> torch.Tensor:
    """Forward-warps a depth map into another camera with a z-buffer.

    Args:
        depth: [H_s, W_s] camera z-depth of the source view.
        intrinsics: [3, 3] source intrinsics. c2w: [3, 4] source camera-to-world.
        target_intrinsics: [3, 3]. target_c2w: [3, 4]. height, width: the target image size.

    Returns:
        [height, width] camera z-depth (in the target camera) of the nearest source point landing on each target
        pixel; +inf where none lands.
    """
    assert depth.ndim == 2, f"depth must be [H, W], got {tuple(depth.shape)}"
    like = {"device": depth.device, "dtype": depth.dtype}
    h, w = depth.shape
    keep = _valid(depth).reshape(-1)
    uv = pixel_grid(h, w, depth.device)[keep]  # [P, 2]
    origins, directions = pixel_rays(intrinsics.to(**like)[None], c2w.to(**like)[None], uv)
    points = origins + depth.reshape(-1)[keep, None] * directions  # [P, 3]
    target_uv, z = project(points, target_intrinsics.to(**like)[None], target_c2w.to(**like)[None])
    pixel = torch.round(target_uv)
    inside = (
        (z > 0) & (pixel[:, 0] >= 0) & (pixel[:, 0] <= width - 1) & (pixel[:, 1] >= 0) & (pixel[:, 1] <= height - 1)
    )
    pixel, z = pixel[inside].long(), z[inside]
    warped = torch.full((height * width,), float("inf"), **like)
    # amin over all points per pixel: the z-buffer, without a loop over pixels.
    warped.scatter_reduce_(0, pixel[:, 1] * width + pixel[:, 0], z, reduce="amin", include_self=True)
    return warped.reshape(height, width)


def seen_by_view(
    test_depth: torch.Tensor,
    test_intrinsics: torch.Tensor,
    test_c2w: torch.Tensor,
    train_depth: torch.Tensor,
    train_intrinsics: torch.Tensor,
    train_c2w: torch.Tensor,
    relative_tolerance: float = RELATIVE_TOLERANCE,
) -> torch.Tensor:
    """The test pixels one train view sees.

    Args:
        test_depth: [H, W] reference depth of the test view. test_intrinsics: [3, 3]. test_c2w: [3, 4].
        train_depth: [H_s, W_s] reference depth of the train view. train_intrinsics: [3, 3]. train_c2w: [3, 4].
        relative_tolerance: depths agree within this fraction of the train view's maximum (valid) depth.

    Returns:
        [H, W] bool.
    """
    h, w = test_depth.shape
    warped = forward_warp_depth(train_depth, train_intrinsics, train_c2w, test_intrinsics, test_c2w, h, w)
    valid = _valid(train_depth)
    if not valid.any():
        return torch.zeros(h, w, dtype=torch.bool, device=test_depth.device)
    threshold = relative_tolerance * train_depth[valid].max()
    # Non-finite test depths and pixels nothing landed on compare as NaN or inf: never seen.
    return (warped - test_depth.to(warped)).abs() < threshold


def visibility_counts(
    test_depth: torch.Tensor,
    test_intrinsics: torch.Tensor,
    test_c2w: torch.Tensor,
    train_depths: torch.Tensor,
    train_intrinsics: torch.Tensor,
    train_c2w: torch.Tensor,
    relative_tolerance: float = RELATIVE_TOLERANCE,
) -> torch.Tensor:
    """How many train views see each test pixel.

    Args:
        test_depth: [H, W]. test_intrinsics: [3, 3]. test_c2w: [3, 4].
        train_depths: [V, H_s, W_s]. train_intrinsics: [V, 3, 3]. train_c2w: [V, 3, 4].
        relative_tolerance: see `seen_by_view`.

    Returns:
        [H, W] int64 counts in [0, V].
    """
    assert train_depths.ndim == 3 and len(train_depths) == len(train_intrinsics) == len(train_c2w), (
        f"train views disagree: depths {tuple(train_depths.shape)}, intrinsics {tuple(train_intrinsics.shape)}, "
        f"c2w {tuple(train_c2w.shape)}"
    )
    counts = torch.zeros(test_depth.shape, dtype=torch.int64, device=test_depth.device)
    for depth, intrinsics, c2w in zip(train_depths, train_intrinsics, train_c2w, strict=True):
        counts += seen_by_view(test_depth, test_intrinsics, test_c2w, depth, intrinsics, c2w, relative_tolerance)
    return counts


def visibility_mask(
    test_depth: torch.Tensor,
    test_intrinsics: torch.Tensor,
    test_c2w: torch.Tensor,
    train_depths: torch.Tensor,
    train_intrinsics: torch.Tensor,
    train_c2w: torch.Tensor,
    min_views: int = MIN_VIEWS,
    relative_tolerance: float = RELATIVE_TOLERANCE,
) -> torch.Tensor:
    """The test pixels seen by at least `min_views` train views (arguments as in `visibility_counts`).

    Returns:
        [H, W] bool, True on pixels to evaluate.
    """
    counts = visibility_counts(test_depth, test_intrinsics, test_c2w, train_depths, train_intrinsics, train_c2w,
                               relative_tolerance)
    return counts >= min_views


def scene_visibility_masks(
    views: Views,
    train: Sequence[int],
    test: Sequence[int],
    min_views: int = MIN_VIEWS,
    relative_tolerance: float = RELATIVE_TOLERANCE,
    progress: bool = True,
) -> dict[int, torch.Tensor]:
    """Visibility masks of the test frames of a scene from its train frames.

    Args:
        views: all frames of the scene, with reference depths (`views.depths` [N, H, W]).
        train, test: frame indices into `views`.
        min_views, relative_tolerance: see `visibility_mask`.
        progress: show a progress bar over the test frames.

    Returns:
        test frame index -> [H, W] bool mask.
    """
    if views.depths is None:
        raise ValueError("visibility masks need reference depths (views.depths is None)")
    train = list(train)
    masks = {}
    for i in tqdm(list(test), desc="visibility masks", unit="frame", disable=not progress):
        masks[i] = visibility_mask(
            views.depths[i], views.intrinsics[i], views.c2w[i], views.depths[train], views.intrinsics[train],
            views.c2w[train], min_views, relative_tolerance,
        )
    return masks


__all__ = [
    "MIN_VIEWS",
    "RELATIVE_TOLERANCE",
    "forward_warp_depth",
    "scene_visibility_masks",
    "seen_by_view",
    "visibility_counts",
    "visibility_mask",
]
