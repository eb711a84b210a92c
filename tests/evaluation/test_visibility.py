"""Tests of evaluation.visibility: exact hand-made cases (z-buffer, a known occlusion, the bilinear footprint) and, on
the synthetic scene with exact depth, forward warping against the protocol's criterion evaluated by ray tracing."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage
import torch

from simplenerf.data.llff import load_llff_scene
from simplenerf.evaluation.visibility import (
    MIN_VIEWS,
    RELATIVE_TOLERANCE,
    SNAP,
    forward_warp_depth,
    scene_visibility_masks,
    seen_by_view,
    splat,
    visibility_counts,
)
from simplenerf.geometry.rays import pixel_rays, project
from simplenerf.synthetic.generate import build_scene, trace_rays, trace_view

# ---------------------------------------------------------------------------------------------------------------------
# A hand-made scene: three cameras with identity rotation at x = 0 (test), +1 (A) and -1 (B), all at y = z = 0 and
# looking along -z; a background plane at z = -10 and an occluding rectangle at z = -4 with x in [0.5, 1.5],
# |y| <= 1. Images 41x41, focal 40, principal point (20, 20).
SIZE, FOCAL, CENTRE = 41, 40.0, 20.0
OCCLUDER_X, OCCLUDER_Y, OCCLUDER_Z, BACKGROUND_Z = (0.5, 1.5), 1.0, 4.0, 10.0


def _intrinsics() -> torch.Tensor:
    return torch.tensor([[FOCAL, 0.0, CENTRE], [0.0, FOCAL, CENTRE], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _camera(x: float) -> torch.Tensor:
    c2w = torch.zeros(3, 4, dtype=torch.float64)
    c2w[:, :3] = torch.eye(3)
    c2w[0, 3] = x
    return c2w


def _analytic_depth(camera_x: float) -> torch.Tensor:
    """Exact camera z-depth [41, 41] of the occluder-and-background scene seen from a camera at (camera_x, 0, 0)."""
    v, u = torch.meshgrid(torch.arange(SIZE, dtype=torch.float64), torch.arange(SIZE, dtype=torch.float64),
                          indexing="ij")
    x = camera_x + OCCLUDER_Z * (u - CENTRE) / FOCAL  # where the ray crosses the occluder's plane
    y = -OCCLUDER_Z * (v - CENTRE) / FOCAL
    on_occluder = (x >= OCCLUDER_X[0]) & (x <= OCCLUDER_X[1]) & (y.abs() <= OCCLUDER_Y)
    return torch.where(on_occluder, OCCLUDER_Z, BACKGROUND_Z)


def _test_pixel_of(x: float, z: float) -> tuple[int, int]:
    """(row, column) of the world point (x, 0, -z) in the test camera (exact for the points used below)."""
    return int(CENTRE), int(round(CENTRE + FOCAL * x / z))


def _occlusion_case() -> dict[str, torch.Tensor]:
    k = _intrinsics()
    return {
        "test_depth": _analytic_depth(0.0), "test_intrinsics": k, "test_c2w": _camera(0.0),
        "train_depths": torch.stack([_analytic_depth(1.0), _analytic_depth(-1.0)]),
        "train_intrinsics": torch.stack([k, k]), "train_c2w": torch.stack([_camera(1.0), _camera(-1.0)]),
    }


def test_identity_warp_returns_the_depth_and_marks_invalid_depths_as_holes() -> None:
    depth = _analytic_depth(0.3).float()
    depth[3, 4], depth[5, 6], depth[7, 8] = 0.0, float("inf"), float("nan")
    k, c2w = _intrinsics().float(), _camera(0.3).float()
    warped = forward_warp_depth(depth, k, c2w, k, c2w, SIZE, SIZE)
    assert warped.dtype == torch.float32
    valid = torch.isfinite(depth) & (depth > 0)
    torch.testing.assert_close(warped[valid], depth[valid], rtol=1e-5, atol=0.0)
    assert torch.isinf(warped[~valid]).all() and int((~valid).sum()) == 3


def test_translation_shifts_by_the_disparity_and_drops_points_outside() -> None:
    # A fronto-parallel plane at depth 10 seen from x = 0, warped into a camera at x = +1: every point moves
    # f * 1 / 10 = 4 pixels left, so the 4 right-most target columns receive nothing.
    depth = torch.full((SIZE, SIZE), BACKGROUND_Z, dtype=torch.float64)
    warped = forward_warp_depth(depth, _intrinsics(), _camera(0.0), _intrinsics(), _camera(1.0), SIZE, SIZE)
    assert torch.equal(warped[:, : SIZE - 4], torch.full((SIZE, SIZE - 4), BACKGROUND_Z, dtype=torch.float64))
    assert torch.isinf(warped[:, SIZE - 4 :]).all()


def test_points_behind_the_target_camera_are_dropped() -> None:
    # The target camera sits 20 units in front of the source, beyond the plane at depth 10, looking the same way.
    depth = torch.full((SIZE, SIZE), BACKGROUND_Z, dtype=torch.float64)
    target = _camera(0.0)
    target[2, 3] = -20.0
    warped = forward_warp_depth(depth, _intrinsics(), _camera(0.0), _intrinsics(), target, SIZE, SIZE)
    assert torch.isinf(warped).all()


def test_known_occlusion_is_invisible_with_two_views() -> None:
    case = _occlusion_case()
    hidden_from_a = _test_pixel_of(0.5, BACKGROUND_Z)  # background point behind the occluder as seen from A
    on_occluder = _test_pixel_of(1.0, OCCLUDER_Z)  # the occluder itself, seen by all three cameras
    open_background = _test_pixel_of(-2.0, BACKGROUND_Z)  # background nobody's view of is blocked
    # The geometry the pixels were chosen by: the segment from A (1, 0, 0) to (0.5, 0, -10) crosses z = -4 at
    # x = 0.8, on the occluder; from B (-1, 0, 0) it crosses at x = -0.4, beside it.
    assert 0.5 <= 1.0 + 0.4 * (0.5 - 1.0) <= 1.5 and not 0.5 <= -1.0 + 0.4 * (0.5 + 1.0) <= 1.5

    seen_a = seen_by_view(case["test_depth"], case["test_intrinsics"], case["test_c2w"], case["train_depths"][0],
                          case["train_intrinsics"][0], case["train_c2w"][0])
    seen_b = seen_by_view(case["test_depth"], case["test_intrinsics"], case["test_c2w"], case["train_depths"][1],
                          case["train_intrinsics"][1], case["train_c2w"][1])
    assert not seen_a[hidden_from_a] and seen_b[hidden_from_a]
    # B sees the background behind the test view's occluder pixels too; only the z-buffer keeps them seen by B.
    assert seen_a[on_occluder] and seen_b[on_occluder]
    assert seen_a[open_background] and seen_b[open_background]

    counts = visibility_counts(**case)
    assert counts.dtype == torch.int64 and torch.equal(counts, seen_a.long() + seen_b.long())
    mask = counts >= MIN_VIEWS
    assert mask.dtype == torch.bool and mask.shape == (SIZE, SIZE)
    assert not mask[hidden_from_a] and mask[on_occluder] and mask[open_background]
    assert counts[hidden_from_a] == 1
    # Every pixel of the strip hidden from A (background x in [-0.25, 1.25) at z = -10, rows of the occluder's
    # shadow) is invisible: columns 19 .. 24 of the centre row.
    assert not mask[int(CENTRE), 19:25].any() and mask[int(CENTRE), 18] and mask[int(CENTRE), 25]


def test_depth_tolerance_is_relative_to_the_train_views_max_depth() -> None:
    case = _occlusion_case()
    # Test depths off by 0.49 (< 0.05 * 10) still match; off by 0.51 do not.
    near_miss = {**case, "test_depth": case["test_depth"] + 0.49}
    assert visibility_counts(**near_miss)[_test_pixel_of(-2.0, BACKGROUND_Z)] == 2
    too_far = {**case, "test_depth": case["test_depth"] + 0.51}
    assert not (visibility_counts(**too_far) >= MIN_VIEWS).any()
    assert RELATIVE_TOLERANCE == 0.05


# ---------------------------------------------------------------------------------------------------------------------
# The synthetic scene with exact depth, in world units (no loader transforms): `_exact_seen` evaluates the protocol's
# criterion exactly, without pixels, by ray tracing.


def _intrinsics_of(focal: float, height: int, width: int) -> torch.Tensor:
    """The synthetic scene's intrinsics: principal point at the image centre (synthetic module docstring)."""
    return torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _exact_seen(scene, test_c2w: np.ndarray, test_focal: float, train_c2w: np.ndarray, train_focal: float, height: int,
                width: int, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The protocol's criterion without discretisation: a test pixel is seen if its surface point projects into the
    train view's pixel grid ([0, W-1] x [0, H-1], in front) and the train view's own ray through that continuous
    position first hits the scene at a z-depth within `tolerance` of the point's. Returns (seen, test depth)."""
    depth, _, _ = trace_view(scene, test_c2w, height, width, test_focal)
    v, u = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    rays = np.stack([(u - width / 2) / test_focal, -(v - height / 2) / test_focal, -np.ones((height, width))], -1)
    points = test_c2w[:, 3] + depth[..., None] * (rays @ test_c2w[:, :3].T)
    p_cam = (points - train_c2w[:, 3]) @ train_c2w[:, :3]
    z = -p_cam[..., 2]
    u_train = train_focal * p_cam[..., 0] / z + width / 2
    v_train = -train_focal * p_cam[..., 1] / z + height / 2
    inside = (z > 0) & (u_train >= 0) & (u_train <= width - 1) & (v_train >= 0) & (v_train <= height - 1)
    train_rays = np.stack([(u_train - width / 2) / train_focal, -(v_train - height / 2) / train_focal,
                           -np.ones_like(z)], -1) @ train_c2w[:, :3].T
    first_hit, _, _ = trace_rays(scene, train_c2w[:, 3], train_rays)
    return inside & (np.abs(first_hit - z) < tolerance), depth


def _nearest_pixel_seen(test_depth, test_k, test_c2w, train_depth, train_k, train_c2w) -> np.ndarray:
    """The previous rule, for comparison: each train point lands on its nearest test pixel only (z-buffer)."""
    height, width = test_depth.shape
    uv = torch.stack(torch.meshgrid(torch.arange(width), torch.arange(height), indexing="xy"), -1).reshape(-1, 2)
    origins, directions = pixel_rays(train_k[None], train_c2w[None], uv)
    target_uv, z = project(origins + train_depth.reshape(-1, 1) * directions, test_k[None], test_c2w[None])
    col, row = target_uv.round().long().unbind(-1)
    keep = (z > 0) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    warped = torch.full((height * width,), float("inf"), dtype=torch.float64)
    warped.scatter_reduce_(0, row[keep] * width + col[keep], z[keep], reduce="amin")
    threshold = RELATIVE_TOLERANCE * train_depth.max()
    return ((warped.reshape(height, width) - test_depth).abs() < threshold).numpy()


def _rotation(axis: tuple[float, float, float], degrees: float) -> np.ndarray:
    """Rodrigues' rotation matrix about `axis`."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


def _band(mask: np.ndarray) -> np.ndarray:
    """Pixels within one pixel (8-neighbourhood) of the boundary between `mask` and its complement."""
    ring = np.ones((3, 3), dtype=bool)
    return scipy.ndimage.binary_dilation(mask, ring) & scipy.ndimage.binary_dilation(~mask, ring)


def test_a_zoomed_and_rotated_test_view_has_no_holes() -> None:
    """The test camera is a train camera of the 96x128 scene, zoomed in 2% and turned 1 degree about (1, 1, 1), at the
    same centre: no parallax, so every test pixel whose point projects into the train image is truly seen. The train
    pixels land 1.02 pixels apart: bilinear footprints cover every test pixel (measured: 0 of them missed), rounding
    each point to its nearest pixel leaves 1-pixel holes (measured: 5.4 % missed)."""
    scene = build_scene(0, height=96, width=128, n_frames=20)
    h, w, focal = scene.height, scene.width, scene.focal
    train_c2w = scene.c2w[6]
    test_c2w = train_c2w.copy()
    test_c2w[:, :3] = train_c2w[:, :3] @ _rotation((1.0, 1.0, 1.0), 1.0)
    train_depth, _, _ = trace_view(scene, train_c2w, h, w, focal)
    truth, test_depth = _exact_seen(scene, test_c2w, 1.02 * focal, train_c2w, focal, h, w,
                                    RELATIVE_TOLERANCE * train_depth.max())
    assert 0.98 < truth.mean() < 0.99  # the rotation turns ~1.6 % of the test view outside the train image
    cameras = (torch.from_numpy(test_depth), _intrinsics_of(1.02 * focal, h, w), torch.from_numpy(test_c2w),
               torch.from_numpy(train_depth), _intrinsics_of(focal, h, w), torch.from_numpy(train_c2w))
    seen = seen_by_view(*cameras).numpy()
    assert (truth & ~seen).sum() / truth.sum() < 0.005
    assert (truth & ~_nearest_pixel_seen(*cameras)).sum() / truth.sum() > 0.04
    # Seen without being truly seen: only the last row / column of the train image's footprint (points of its edge
    # pixels land up to a pixel further out).
    assert not (seen & ~truth & ~_band(truth)).any()


def test_split_views_match_the_exact_criterion_up_to_one_pixel_at_its_edges() -> None:
    """The scene's own 2-view split (train frames 6 and 13, test frames 0, 8 and 16) at 48x64, with parallax and
    occlusions: no truly seen pixel is missed, and the pixels seen without being truly seen all lie within one pixel
    of the edge of the truly seen region (a footprint reaches one pixel into a region the train view does not see;
    the authors' bilinear splatting does the same). The masks (seen by both) then agree likewise. Measured: 4.2-6.7 %
    of the pixels are seen without being truly seen (nearest-pixel rounding: 2.0-3.3 %, but it misses 1.6-4.1 %)."""
    scene = build_scene(0, height=48, width=64, n_frames=20)
    h, w, focal = scene.height, scene.width, scene.focal
    k = _intrinsics_of(focal, h, w)
    train_depths = [trace_view(scene, scene.c2w[i], h, w, focal)[0] for i in (6, 13)]
    for test in (0, 8, 16):
        counts, bands = np.zeros((h, w), dtype=int), np.zeros((h, w), dtype=bool)
        for train, train_depth in zip((6, 13), train_depths, strict=True):
            truth, test_depth = _exact_seen(scene, scene.c2w[test], focal, scene.c2w[train], focal, h, w,
                                            RELATIVE_TOLERANCE * train_depth.max())
            seen = seen_by_view(torch.from_numpy(test_depth), k, torch.from_numpy(scene.c2w[test]),
                                torch.from_numpy(train_depth), k, torch.from_numpy(scene.c2w[train])).numpy()
            assert (~truth).sum() > 100  # occlusions and the image border hide part of the test view
            assert not (truth & ~seen).any(), f"frame {test} from {train}: truly seen pixels missed"
            assert not (seen & ~truth & ~_band(truth)).any(), f"frame {test} from {train}: seen far from the truth"
            counts += truth
            bands |= _band(truth)
        mask = visibility_counts(torch.from_numpy(test_depth), k, torch.from_numpy(scene.c2w[test]),
                                 torch.from_numpy(np.stack(train_depths)), torch.stack([k, k]),
                                 torch.from_numpy(scene.c2w[[6, 13]])).numpy() >= MIN_VIEWS
        truth_mask = counts >= 2
        assert not (truth_mask & ~mask).any()
        assert not (mask & ~truth_mask & ~bands).any()


def test_splat_lands_on_the_bilinear_footprint() -> None:
    uv = torch.tensor([[2.25, 1.5], [4.0, 3.0], [4.0000001, 2.9999999], [-0.5, 0.0], [1.0, 1.0], [5.5, 3.0]],
                      dtype=torch.float64)
    z = torch.tensor([1.0, 2.0, 3.0, 4.0, -1.0, 6.0], dtype=torch.float64)
    pixel, depth = splat(uv, z, height=4, width=6)
    landed = sorted(zip(pixel.tolist(), depth.tolist(), strict=True))
    # (2.25, 1.5): columns 2-3 x rows 1-2. Exactly on (4, 3), or within SNAP of it: that pixel alone.
    # (-0.5, 0): column -1 is outside, column 0 stays. z <= 0: dropped. (5.5, 3): column 6 is outside.
    expected = [(1 * 6 + 2, 1.0), (1 * 6 + 3, 1.0), (2 * 6 + 2, 1.0), (2 * 6 + 3, 1.0), (3 * 6 + 4, 2.0),
                (3 * 6 + 4, 3.0), (0 * 6 + 0, 4.0), (3 * 6 + 5, 6.0)]
    assert landed == sorted(expected) and SNAP == 1e-3


@pytest.fixture(scope="module")
def two_view_scene(synthetic_scene):
    return load_llff_scene(synthetic_scene, factor=1, n_views=2)


def test_scene_masks_need_reference_depth(two_view_scene) -> None:
    views = two_view_scene.views
    without = type(views)(views.images, views.intrinsics, views.c2w, views.names, None)
    with pytest.raises(ValueError, match="reference depths"):
        scene_visibility_masks(without, [6, 13], [0], progress=False)


def test_scene_masks_keys_shapes_and_more_views_see_more(synthetic_scene) -> None:
    two = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    four = load_llff_scene(synthetic_scene, factor=1, n_views=4)
    masks2 = scene_visibility_masks(two.views, two.split.train, two.split.test, progress=False)
    masks4 = scene_visibility_masks(four.views, four.split.train, four.split.test, progress=False)
    assert list(masks2) == [0, 8, 16]
    assert all(m.shape == (48, 64) and m.dtype == torch.bool for m in masks2.values())
    assert sum(m.float().mean() for m in masks4.values()) > sum(m.float().mean() for m in masks2.values())
    assert all(0.5 < m.float().mean() < 1.0 for m in masks2.values())
