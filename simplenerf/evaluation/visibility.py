"""Visibility masks of test views (supplement, Evaluation Details; the release's src/qa/00_Common/src/mask_generators/
VisibilityMask02_NeRF_LLFF.py): the test pixels whose surface the train views saw, by reference depth.

The paper evaluates masked scores over the pixels that at least two train views saw. Whether a train view saw a test
pixel is decided by forward warping with bilinear splatting (as the authors' evaluation does), not by backward
projection:

1. Every pixel of the train view is lifted to 3D with its reference depth: point = o + z d with the un-normalised ray
   direction of `rays.pixel_rays`, so z is the camera z-depth (the conventions of `simplenerf.geometry.rays`).
2. The points are projected into the test camera (`rays.project`); points behind it (z <= 0) are dropped. Each point
   lands on the 4 test pixels around its continuous position (its bilinear footprint, `splat`), each with its
   bilinear weight; pixels of weight 0 are not landed on, so a point exactly on a pixel lands there alone.
   Coordinates within `SNAP` pixels of a pixel are snapped to it, so that float rounding cannot spread an exact
   landing over the neighbours with weights of 1e-7.
3. A test pixel is seen by that train view if some point landing on it has a depth (in the test camera) within
   0.05 x the train view's maximum depth of the test view's reference depth; it is visible if seen by at least
   `min_views` (2) train views. With 2 train views that means both.

Since neighbouring train pixels land less than 2 test pixels apart unless the test view magnifies the train view
2x, every test pixel of a surface the train view sees receives a point of that surface: no holes where the test view
zooms in or rotates (rounding each point to its nearest pixel instead leaves 1-pixel holes wherever the train pixels
land more than 1 pixel apart: 4-6% of the pixels for a 2% zoom of the synthetic scene). A surface hidden from the
train view sends no point to the pixels where the test view sees it, so occlusions stay invisible. The authors'
release splats the same footprints but compares one depth per pixel, the footprint-weighted mean of the landed
depths under a steep soft z-buffer (weight / exp(50 log(1 + z) / log(1 + z_max))); the two differ only in pixels
where two surfaces land, i.e. within a pixel of a depth edge, where the release's mean follows the nearer surface.

Depth maps are [H, W] camera z-depths in scene units. Depths that are not finite or not positive are never warped and
never match, so a pixel without reference depth is never visible.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tqdm import tqdm

from simplenerf.geometry.rays import pixel_grid, pixel_rays, project
from simplenerf.geometry.views import Views

RELATIVE_TOLERANCE = 0.05
"""A train view sees a test pixel if the depths agree within this fraction of the train view's maximum depth."""

MIN_VIEWS = 2
"""A test pixel is evaluated (visible) if at least this many train views see it."""

SNAP = 1e-3
"""Projected coordinates within this many pixels of a pixel land on that pixel alone (float noise of exact hits)."""


def _valid(depth: torch.Tensor) -> torch.Tensor:
    return torch.isfinite(depth) & (depth > 0)


def _warp_points(
    depth: torch.Tensor,
    intrinsics: torch.Tensor,
    c2w: torch.Tensor,
    target_intrinsics: torch.Tensor,
    target_c2w: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The valid pixels of a source depth map as points in the target camera: uv [P, 2] continuous pixel
    coordinates and z [P] camera z-depth (possibly <= 0: behind the target camera), dtype of depth."""
    assert depth.ndim == 2, f"depth must be [H, W], got {tuple(depth.shape)}"
    like = {"device": depth.device, "dtype": depth.dtype}
    h, w = depth.shape
    keep = _valid(depth).reshape(-1)
    uv = pixel_grid(h, w, depth.device)[keep]  # [P, 2]
    origins, directions = pixel_rays(intrinsics.to(**like)[None], c2w.to(**like)[None], uv)
    points = origins + depth.reshape(-1)[keep, None] * directions  # [P, 3]
    return project(points, target_intrinsics.to(**like)[None], target_c2w.to(**like)[None])


def splat(uv: torch.Tensor, z: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The bilinear footprints of points in an image: every (pixel, point) pair of positive bilinear weight.

    Args:
        uv: [P, 2] continuous pixel coordinates (column, row). z: [P] depths; points with z <= 0 (or NaN) are dropped.
        height, width: the image size; footprint pixels outside it are dropped.

    Returns:
        pixel [K] flat pixel indices (row * width + column) and depth [K] the depth of the point landing there,
        K <= 4 P.
    """
    snapped = torch.where((uv - uv.round()).abs() < SNAP, uv.round(), uv)
    base = torch.floor(snapped)
    frac = snapped - base  # [P, 2] in [0, 1)
    pixels, depths = [], []
    for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
        weight = (frac[:, 0] if du else 1 - frac[:, 0]) * (frac[:, 1] if dv else 1 - frac[:, 1])
        col, row = base[:, 0] + du, base[:, 1] + dv
        keep = (weight > 0) & (z > 0) & (col >= 0) & (col <= width - 1) & (row >= 0) & (row <= height - 1)
        pixels.append((row[keep] * width + col[keep]).long())
        depths.append(z[keep])
    return torch.cat(pixels), torch.cat(depths)


def forward_warp_depth(
    depth: torch.Tensor,
    intrinsics: torch.Tensor,
    c2w: torch.Tensor,
    target_intrinsics: torch.Tensor,
    target_c2w: torch.Tensor,
    height: int,
    width: int,
) -> torch.Tensor:
    """Forward-warps a depth map into another camera with bilinear footprints and a z-buffer.

    Args:
        depth: [H_s, W_s] camera z-depth of the source view.
        intrinsics: [3, 3] source intrinsics. c2w: [3, 4] source camera-to-world.
        target_intrinsics: [3, 3]. target_c2w: [3, 4]. height, width: the target image size.

    Returns:
        [height, width] camera z-depth (in the target camera) of the nearest source point whose bilinear footprint
        covers each target pixel (`splat`); +inf where none does.
    """
    uv, z = _warp_points(depth, intrinsics, c2w, target_intrinsics, target_c2w)
    pixel, z = splat(uv, z, height, width)
    warped = torch.full((height * width,), float("inf"), device=depth.device, dtype=depth.dtype)
    # amin over all landings per pixel: the z-buffer, without a loop over pixels.
    warped.scatter_reduce_(0, pixel, z, reduce="amin", include_self=True)
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
    """The test pixels one train view sees: those where one of its points lands (`splat`) at a matching depth.

    Args:
        test_depth: [H, W] reference depth of the test view. test_intrinsics: [3, 3]. test_c2w: [3, 4].
        train_depth: [H_s, W_s] reference depth of the train view. train_intrinsics: [3, 3]. train_c2w: [3, 4].
        relative_tolerance: depths agree within this fraction of the train view's maximum (valid) depth.

    Returns:
        [H, W] bool.
    """
    h, w = test_depth.shape
    valid = _valid(train_depth)
    if not valid.any():
        return torch.zeros(h, w, dtype=torch.bool, device=test_depth.device)
    threshold = relative_tolerance * train_depth[valid].max()
    uv, z = _warp_points(train_depth, train_intrinsics, train_c2w, test_intrinsics, test_c2w)
    pixel, z = splat(uv, z, h, w)
    # A landing at a non-finite test depth compares as NaN or inf: never seen.
    match = (z - test_depth.to(z).reshape(-1)[pixel]).abs() < threshold
    seen = torch.zeros(h * w, dtype=torch.uint8, device=test_depth.device)
    seen.scatter_reduce_(0, pixel, match.to(torch.uint8), reduce="amax")  # any match per pixel, no host sync
    return seen.reshape(h, w).bool()


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
        min_views: a pixel is evaluated when at least this many train views see it (the release: 2).
        relative_tolerance: see `seen_by_view`.
        progress: show a progress bar over the test frames.

    Returns:
        test frame index -> [H, W] bool mask.
    """
    if views.depths is None:
        raise ValueError("visibility masks need reference depths (views.depths is None)")
    train = list(train)
    masks = {}
    for i in tqdm(list(test), desc="visibility masks", unit="frame", disable=not progress):
        counts = visibility_counts(
            views.depths[i], views.intrinsics[i], views.c2w[i], views.depths[train], views.intrinsics[train],
            views.c2w[train], relative_tolerance,
        )
        masks[i] = counts >= min_views
    return masks


__all__ = [
    "MIN_VIEWS",
    "RELATIVE_TOLERANCE",
    "forward_warp_depth",
    "SNAP",
    "scene_visibility_masks",
    "seen_by_view",
    "splat",
    "visibility_counts",
]
