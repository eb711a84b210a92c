"""Reliability masks (Sec. 4.2): nearest views, patch reprojection errors against exact depth, the ternary mask and
the gradient routing of the masked depth losses."""

from __future__ import annotations

import math

import pytest
import torch

from simplenerf.data.batches import RayBatch
from simplenerf.data.llff import load_llff_scene, subset
from simplenerf.geometry.rays import RayBundle, pixel_rays, project
from simplenerf.geometry.views import Views
from simplenerf.method.reliability import (
    PatchReprojectionMask,
    ReprojectionErrors,
    TrustAll,
    limited_square,
    mask_fractions,
    masked_depth_loss,
    nearest_views,
    patch_reprojection_error,
    patch_texture,
    ternary_mask,
)
from simplenerf.synthetic.generate import make_synthetic_scene

K = 5  # the paper's patch size
THRESHOLD = 0.1


@pytest.fixture(scope="module")
def train_views(synthetic_scene) -> Views:
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=3)
    return subset(scene.views, scene.split.train)


@pytest.fixture(scope="module")
def sharp_views(tmp_path_factory) -> Views:
    """The same synthetic scene (same seed: geometry, textures, cameras) on a 3x finer pixel grid.

    At the shared fixture's 48x64 the procedural textures reach wavelengths of 2.5 px, so rounding the reprojected
    pixel (up to half a pixel) alone gives a median patch RMSE of ~0.1 for the EXACT depth, and two of its three
    train views are only ~0.3 px of disparity apart. At 144x192 the exact depth's median RMSE is ~0.035, which is
    what the statistical claims below need.
    """
    root = make_synthetic_scene(tmp_path_factory.mktemp("sharp") / "scene", height=144, width=192, n_frames=20)
    scene = load_llff_scene(root, factor=1, n_views=3)
    return subset(scene.views, scene.split.train)


def pixel_grid(views: Views, stride: int = 1) -> dict[str, torch.Tensor]:
    """Rays at every stride-th pixel of every view, with the exact depth there."""
    v, row, col = torch.meshgrid(
        torch.arange(len(views)),
        torch.arange(0, views.height, stride),
        torch.arange(0, views.width, stride),
        indexing="ij",
    )
    view, uv = v.flatten(), torch.stack([col.flatten(), row.flatten()], dim=-1)
    rays = views.rays(view, uv, near=1.0)
    return {"view": view, "uv": uv, "origins": rays.origins, "directions": rays.directions,
            "depth": views.depths[view, uv[:, 1], uv[:, 0]]}  # fmt: skip


def ray_batch(view: torch.Tensor, uv: torch.Tensor, origins: torch.Tensor, directions: torch.Tensor) -> RayBatch:
    """A batch of world rays (the masks read view, uv, origins and directions; NDC and colours are unused)."""
    return RayBatch(RayBundle(origins, directions, origins, directions), torch.zeros_like(origins), view, uv)


def context(views: Views, batch: dict[str, torch.Tensor]) -> tuple[Views, RayBatch]:
    return views, ray_batch(batch["view"], batch["uv"], batch["origins"], batch["directions"])


def error_of(views: Views, batch: dict[str, torch.Tensor], depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return patch_reprojection_error(*context(views, batch), depth, K)


def visible_in_nearest(views: Views, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """[R] the exact surface point of each ray is the one view b sees at the reprojected pixel (not occluded)."""
    b = nearest_views(views.c2w)[batch["view"]]
    points = batch["origins"] + batch["depth"][:, None] * batch["directions"]
    uv_b, z_b = project(points, views.intrinsics[b], views.c2w[b])
    pixel = torch.round(uv_b).long()
    col, row = pixel[:, 0].clamp(0, views.width - 1), pixel[:, 1].clamp(0, views.height - 1)
    return (views.depths[b, row, col] - z_b).abs() < 0.01 * z_b


# --- nearest views ---------------------------------------------------------------------------------------------


def cameras_at(centres: list[list[float]]) -> torch.Tensor:
    eye = torch.eye(3).expand(len(centres), 3, 3)
    return torch.cat([eye, torch.tensor(centres)[:, :, None]], dim=-1)


def test_nearest_views_on_a_line():
    # Centres at x = 0, 1, 3, 7, 7.5: each one's nearest other camera.
    c2w = cameras_at([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [7.0, 0, 0], [7.5, 0, 0]])
    assert nearest_views(c2w).tolist() == [1, 0, 1, 4, 3]


def test_nearest_views_of_two_views_and_errors():
    assert nearest_views(cameras_at([[0.0, 0, 0], [5.0, 1, 2]])).tolist() == [1, 0]
    with pytest.raises(ValueError, match="at least 2 views"):
        nearest_views(cameras_at([[0.0, 0, 0]]))


# --- patch reprojection error ----------------------------------------------------------------------------------


def test_exact_depth_reprojects_well_and_wrong_depths_do_not(sharp_views):
    batch = pixel_grid(sharp_views, stride=2)
    e_true, valid = error_of(sharp_views, batch, batch["depth"])
    seen = valid & visible_in_nearest(sharp_views, batch)
    assert seen.float().mean() > 0.7
    e = e_true[seen]
    assert e.median() < 0.05
    assert (e < THRESHOLD).float().mean() > 0.8
    for scale, beaten in ((0.6, 0.9), (1.5, 0.8)):
        e_wrong, _ = error_of(sharp_views, batch, batch["depth"] * scale)
        assert (e_wrong[seen] > e).float().mean() > beaten, scale


def test_vectorised_error_matches_a_reference_loop(train_views):
    views = train_views
    g = torch.Generator().manual_seed(0)
    n = 50
    view = torch.randint(len(views), (n,), generator=g)
    # Pixels anywhere (borders included) and depths from behind the camera to beyond the background, around the
    # exact depth for half of the rays so that plenty of them are valid.
    uv = torch.stack([torch.randint(views.width, (n,), generator=g), torch.randint(views.height, (n,), generator=g)], 1)
    origins, directions = pixel_rays(views.intrinsics[view], views.c2w[view], uv)
    exact = views.depths[view, uv[:, 1], uv[:, 0]]
    random_depth = torch.empty(n).uniform_(-2.0, 8.0, generator=g)
    near_exact = exact * torch.empty(n).uniform_(0.9, 1.1, generator=g)
    depth = torch.where(torch.arange(n) % 2 == 0, near_exact, random_depth)
    error, valid = patch_reprojection_error(views, ray_batch(view, uv, origins, directions), depth, K)

    half = K // 2
    for r in range(n):
        a = int(view[r])
        centres = [views.c2w[i, :, 3] for i in range(len(views))]
        b = min((i for i in range(len(views)) if i != a), key=lambda i: float((centres[i] - centres[a]).norm()))
        point = origins[r] + depth[r] * directions[r]
        p = views.c2w[b, :, :3].T @ (point - views.c2w[b, :, 3])
        z_b = -float(p[2])
        fx, fy, cx, cy = (float(views.intrinsics[b, i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
        u_b, v_b = round(fx * float(p[0]) / z_b + cx), round(-fy * float(p[1]) / z_b + cy)
        u_a, v_a = int(uv[r, 0]), int(uv[r, 1])

        def inside(u: int, v: int) -> bool:
            return half <= u <= views.width - 1 - half and half <= v <= views.height - 1 - half

        ok = inside(u_a, v_a) and inside(u_b, v_b) and z_b > 0
        assert bool(valid[r]) == ok, r
        if not ok:
            assert error[r] == math.inf
            continue
        total = 0.0
        for dv in range(-half, half + 1):
            for du in range(-half, half + 1):
                diff = views.images[a, v_a + dv, u_a + du] - views.images[b, v_b + dv, u_b + du]
                total += float((diff**2).sum())
        assert float(error[r]) == pytest.approx(math.sqrt(total / (K * K * 3)), abs=1e-5), r
    assert 10 <= int(valid.sum()) <= 40  # both branches were exercised


def test_point_behind_the_nearest_camera_is_invalid():
    # Camera 1 sits 5 units in front of camera 0, looking the same way: a point 2 units in front of camera 0 is
    # 3 units behind camera 1, yet projects to an in-bounds (mirrored) pixel.
    height, width = 48, 64
    intrinsics = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]]).expand(2, 3, 3)
    c2w = cameras_at([[0.0, 0.0, 0.0], [0.0, 0.0, -5.0]])
    images = torch.rand(2, height, width, 3, generator=torch.Generator().manual_seed(0))
    uv = torch.tensor([[32, 24], [36, 27], [32, 24]])
    view = torch.zeros(3, dtype=torch.long)
    origins, directions = pixel_rays(intrinsics[view], c2w[view], uv)
    depth = torch.tensor([2.0, 2.0, 8.0])
    uv_b, z_b = project(origins + depth[:, None] * directions, intrinsics[1:], c2w[1:])
    assert z_b.tolist() == pytest.approx([-3.0, -3.0, 3.0])
    assert ((uv_b >= K // 2) & (uv_b <= torch.tensor([width, height]) - 1 - K // 2)).all()  # in bounds
    views = Views(images, intrinsics, c2w, ["a", "b"])
    error, valid = patch_reprojection_error(views, ray_batch(view, uv, origins, directions), depth, K)
    assert valid.tolist() == [False, False, True]
    assert error[:2].tolist() == [math.inf, math.inf] and math.isfinite(error[2])


def plane_texture(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """A smooth RGB pattern [..., 3] of world x, y with several orientations (wavelengths 0.7-1.3 units)."""
    two_pi = 2 * math.pi
    return torch.stack(
        [
            0.5 + 0.2 * torch.sin(two_pi * (x / 0.9 + y / 2.1)) + 0.2 * torch.cos(two_pi * y / 1.1),
            0.5 + 0.3 * torch.sin(two_pi * (x - y) / 1.3 + 1.0),
            0.5 + 0.2 * torch.cos(two_pi * x / 0.7) * torch.sin(two_pi * y / 1.2),
        ],
        dim=-1,
    )


def test_reprojection_uses_the_nearest_views_own_intrinsics():
    # Two parallel cameras facing a textured plane at z = -4; camera 1 has a 10% longer focal length and an
    # off-centre principal point, so only its own intrinsics map camera 0's pixels to the right place.
    height, width, plane_depth = 48, 64, 4.0
    k0 = torch.tensor([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]])
    k1 = torch.tensor([[66.0, 0.0, 29.0], [0.0, 66.0, 26.5], [0.0, 0.0, 1.0]])
    intrinsics = torch.stack([k0, k1])
    c2w = cameras_at([[0.0, 0.0, 0.0], [0.3, -0.1, 0.0]])
    row, col = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    uv = torch.stack([col.flatten(), row.flatten()], dim=-1)
    images = []
    for i in range(2):
        o, d = pixel_rays(intrinsics[i : i + 1], c2w[i : i + 1], uv)
        hit = o + plane_depth * d  # camera z-depth of the plane is plane_depth for both cameras
        images.append(plane_texture(hit[:, 0], hit[:, 1]).reshape(height, width, 3))
    images = torch.stack(images)

    view = torch.zeros(len(uv), dtype=torch.long)
    origins, directions = pixel_rays(k0[None], c2w[:1], uv)
    depth = torch.full((len(uv),), plane_depth)
    rays = ray_batch(view, uv, origins, directions)
    error, valid = patch_reprojection_error(Views(images, intrinsics, c2w, ["a", "b"]), rays, depth, K)
    wrong, wrong_valid = patch_reprojection_error(Views(images, torch.stack([k0, k0]), c2w, ["a", "b"]), rays, depth, K)
    both = valid & wrong_valid
    assert both.sum() > 0.5 * len(uv)
    assert error[valid].max() < 0.05
    assert (wrong[both] > 2 * error[both]).float().mean() > 0.9


# --- the ternary mask ------------------------------------------------------------------------------------------


def test_ternary_mask_values_and_strict_comparisons():
    inf = math.inf
    # (main, other): other better and good; main better and good; tie; both above; main invalid; both invalid;
    # other exactly at the threshold (strict <: not trusted).
    e_main = torch.tensor([0.20, 0.05, 0.05, 0.30, inf, inf, 0.20], dtype=torch.float64)
    e_other = torch.tensor([0.05, 0.20, 0.05, 0.20, 0.05, inf, 0.10], dtype=torch.float64)
    mask = ternary_mask(e_main, e_other, threshold=0.1)
    assert mask.dtype == torch.float64
    assert mask.tolist() == [1, -1, 0, 0, 1, 0, 0]


def test_patch_mask_semantics_on_exact_depth(sharp_views):
    batch = pixel_grid(sharp_views, stride=2)
    z_true, z_near, z_far = batch["depth"], batch["depth"] * 0.6, batch["depth"] * 1.5
    ctx = context(sharp_views, batch)
    mask_of = PatchReprojectionMask(patch_size=K, error_threshold=THRESHOLD)
    e_true, valid = error_of(sharp_views, batch, z_true)
    e_near, _ = error_of(sharp_views, batch, z_near)
    e_far, _ = error_of(sharp_views, batch, z_far)
    shared = ReprojectionErrors(*ctx)  # one gather of the source patches for both depths, as in a training step
    for name, z, single in (("near", z_near, e_near), ("true", z_true, e_true)):
        assert torch.equal(shared(name, z, K), single)

    good = valid & (e_true < 0.05) & (e_near > THRESHOLD)
    assert good.sum() > 0.3 * len(z_true)
    assert (mask_of(*ctx, z_near, z_true)[good] == 1).all()  # main wrong, other right: train main
    assert (mask_of(*ctx, z_true, z_near)[good] == -1).all()  # main right, other wrong: train other

    both_bad = valid & (e_near > THRESHOLD) & (e_far > THRESHOLD)
    assert both_bad.sum() > 100
    assert (mask_of(*ctx, z_near, z_far)[both_bad] == 0).all()
    assert (mask_of(*ctx, z_true, z_true) == 0).all()  # equal depths tie everywhere


def test_require_both_valid_judges_only_rays_where_both_depths_land_in_the_nearest_view(sharp_views):
    batch = pixel_grid(sharp_views, stride=4)
    z_true, z_behind = batch["depth"], -batch["depth"]  # behind both cameras: never valid (require_in_front)
    ctx = context(sharp_views, batch)
    e_true, valid = error_of(sharp_views, batch, z_true)
    e_behind, valid_behind = error_of(sharp_views, batch, z_behind)
    assert not valid_behind.any()
    good = valid & (e_true < THRESHOLD)
    assert good.sum() > 0.3 * len(z_true)
    paper = PatchReprojectionMask(K, THRESHOLD)
    both = PatchReprojectionMask(K, THRESHOLD, require_both_valid=True)
    # eq. 6: the depth that leaves the view has error inf, so the other wins wherever its error is below e_tau ...
    assert (paper(*ctx, z_behind, z_true)[good] == 1).all() and (paper(*ctx, z_true, z_behind)[good] == -1).all()
    # ... with require_both_valid neither is trusted there,
    assert (both(*ctx, z_behind, z_true) == 0).all() and (both(*ctx, z_true, z_behind) == 0).all()
    # With a depth that leaves the view on some rays only: the paper's mask where both land, 0 elsewhere (also
    # through `judge`, the training step's path).
    z_near = z_true * 0.6
    _, valid_near = error_of(sharp_views, batch, z_near)
    both_land = valid & valid_near
    assert both_land.any() and (good & ~valid_near).any()  # the paper's mask trusts z_true on those: +1
    expected = torch.where(both_land, paper(*ctx, z_near, z_true), torch.zeros_like(z_true))
    assert torch.equal(both(*ctx, z_near, z_true), expected)
    errors = ReprojectionErrors(*ctx)
    assert torch.equal(both.judge(errors, "near", z_near, "true", z_true), expected)
    assert (both.judge(errors, "behind", z_behind, "true", z_true) == 0).all()


def test_patch_texture_is_the_patchs_pixel_spread():
    plain = torch.full((1, 25, 3), 0.4)
    halves = torch.zeros(1, 4, 3)
    halves[:, 2:, 0] = 1.0  # red 0, 0, 1, 1: std 0.5; green and blue plain
    assert patch_texture(torch.cat([plain[:, :4], halves])).tolist() == pytest.approx([0.0, 0.5 / 3])


def test_min_texture_judges_only_rays_whose_own_patch_is_textured(sharp_views):
    # Every view's left half painted one grey with a little noise (a plain wall): there every depth that lands on
    # the wall passes e_tau and the noise decides which of two depths wins; min_texture leaves those rays unjudged,
    # and the textured rays keep the paper's mask.
    images = sharp_views.images.clone()
    wall = images[:, :, : sharp_views.width // 2]
    wall[...] = 0.5 + 0.005 * torch.randn(wall.shape, generator=torch.Generator().manual_seed(0))
    views = Views(images, sharp_views.intrinsics, sharp_views.c2w, sharp_views.names, sharp_views.depths)
    batch = pixel_grid(views, stride=4)
    ctx = context(views, batch)
    z_true, z_near = batch["depth"], batch["depth"] * 0.6
    errors = ReprojectionErrors(*ctx)
    texture = errors.texture(K)
    assert errors.texture(K) is texture  # computed once per batch, shared by the three masks
    plain = batch["uv"][:, 0] < views.width // 2 - K // 2  # the patch lies on the wall
    assert (texture[plain] < 0.01).all() and (texture[~plain & (texture > 0)] > 0.02).float().mean() > 0.9
    paper = PatchReprojectionMask(K, THRESHOLD)(*ctx, z_near, z_true)
    textured = PatchReprojectionMask(K, THRESHOLD, min_texture=0.02)
    mask = textured(*ctx, z_near, z_true)
    assert (paper[plain] == 1).any() and (paper[plain] == -1).any()  # won by chance, both ways
    assert (mask[plain] == 0).all()
    expected = torch.where(texture >= 0.02, paper, torch.zeros_like(paper))
    assert torch.equal(mask, expected) and torch.equal(textured.judge(errors, "near", z_near, "true", z_true), expected)
    with pytest.raises(ValueError, match="min_texture"):
        PatchReprojectionMask(min_texture=-0.1)


def test_max_pull_back_never_trains_a_depth_toward_a_much_farther_one(sharp_views):
    # A near depth (0.6 of the true one) loses to the true depth: the paper's mask trains it back to the true surface
    # (+1 with the near one as main, -1 with it as other). With max_pull_back 0.2 those rays are left unjudged, since
    # the winner is 1.67 times as far; a winner only 1.1 times as far, and every pull forward, keep the paper's mask.
    batch = pixel_grid(sharp_views, stride=4)
    ctx = context(sharp_views, batch)
    z_true = batch["depth"]
    paper, limited = PatchReprojectionMask(K, THRESHOLD), PatchReprojectionMask(K, THRESHOLD, max_pull_back=0.2)
    for z_near in (z_true * 0.6, z_true / 1.1):
        back = bool((z_true > 1.2 * z_near).all())
        for main, other, pull_back in ((z_near, z_true, 1.0), (z_true, z_near, -1.0)):
            reference, mask = paper(*ctx, main, other), limited(*ctx, main, other)
            assert (reference == pull_back).float().mean() > 0.25  # the true depth wins on many rays
            expected = torch.where(reference == pull_back, 0.0, reference) if back else reference
            assert torch.equal(mask, expected)
            assert torch.equal(limited.judge(ReprojectionErrors(*ctx), "a", main, "b", other), expected)
    with pytest.raises(ValueError, match="max_pull_back"):
        PatchReprojectionMask(max_pull_back=-0.1)


def test_search_radius_finds_the_patch_of_views_that_register_only_to_two_pixels(sharp_views):
    # The nearest view of view 0 shifted two columns to the right (a pose error of 2 px): the exact depth's patch now
    # misses, and with search_radius 2 the shifted patch is among those compared, so its error is at most the
    # registered views' error, ray by ray.
    batch = pixel_grid(sharp_views, stride=2)
    batch = {k: v[batch["view"] == 0] for k, v in batch.items()}
    b = int(nearest_views(sharp_views.c2w)[0])
    images = sharp_views.images.clone()
    images[b] = torch.roll(images[b], shifts=2, dims=1)  # column c now shows what column c - 2 showed
    shifted = Views(images, sharp_views.intrinsics, sharp_views.c2w, sharp_views.names, sharp_views.depths)
    z = batch["depth"]
    registered = ReprojectionErrors(*context(sharp_views, batch))("true", z, K)
    errors = ReprojectionErrors(*context(shifted, batch))
    e0, e2 = errors("true", z, K), errors("true", z, K, search_radius=2)
    assert errors("true", z, K, search_radius=2) is e2 and e2 is not e0  # one computation per radius
    uv_b, _ = project(batch["origins"] + z[:, None] * batch["directions"], sharp_views.intrinsics[b],
                      sharp_views.c2w[b])
    inner = torch.isfinite(registered) & (torch.round(uv_b[:, 0]) < sharp_views.width - 1 - K // 2 - 2)
    assert inner.sum() > 200
    assert torch.equal(torch.isfinite(e2), torch.isfinite(registered))  # validity is the reprojected pixel's
    assert (e2[inner] <= registered[inner]).all()
    seen = inner & visible_in_nearest(sharp_views, batch)
    assert (e0[seen] < THRESHOLD).float().mean() < 0.5 and (e2[seen] < THRESHOLD).float().mean() > 0.9  # 0.13, 0.94
    # The mask trusts the exact depth over a wrong one again where the one-patch comparison could not tell them
    # apart, wherever the wrong depth reprojects beyond the window (2 px) and a patch (5 px) from the shifted one.
    wrong = 0.3 * z
    uv_wrong, _ = project(batch["origins"] + wrong[:, None] * batch["directions"], sharp_views.intrinsics[b],
                          sharp_views.c2w[b])
    apart = seen & ((uv_wrong - uv_b).abs().max(dim=-1).values > 2 + 2 + K)
    mask0, mask2, registered_mask = (PatchReprojectionMask(K, THRESHOLD, search_radius=r)(*context(v, batch), wrong, z)
                                     for v, r in ((shifted, 0), (shifted, 2), (sharp_views, 0)))
    trusted = [(m[apart] == 1).float().mean() for m in (mask0, mask2, registered_mask)]  # 0.21, 0.92, 0.90
    assert apart.sum() > 1000 and trusted[0] < 0.4 and trusted[1] > 0.85 and trusted[1] > trusted[2] - 0.02
    with pytest.raises(ValueError, match="search_radius"):
        PatchReprojectionMask(search_radius=-1)


def test_patch_mask_is_zero_near_the_border(train_views):
    # Rays of view 0 one pixel closer to the border than k // 2, with the exact depth for "other" and a wrong one
    # for "main": in the interior this would be +1.
    half = K // 2
    uv = torch.tensor([[half - 1, 20], [30, half - 1], [train_views.width - half, 20], [30, train_views.height - 1]])
    view = torch.zeros(len(uv), dtype=torch.long)
    rays = train_views.rays(view, uv, near=1.0)
    batch = {"view": view, "uv": uv, "origins": rays.origins, "directions": rays.directions,
             "depth": train_views.depths[view, uv[:, 1], uv[:, 0]]}  # fmt: skip
    e, valid = error_of(train_views, batch, batch["depth"])
    assert not valid.any() and (e == math.inf).all()
    mask = PatchReprojectionMask(K, THRESHOLD)(*context(train_views, batch), batch["depth"] * 0.6, batch["depth"])
    assert mask.tolist() == [0, 0, 0, 0]


def test_constructor_checks():
    with pytest.raises(ValueError, match="odd"):
        PatchReprojectionMask(patch_size=4)
    with pytest.raises(ValueError, match="positive"):
        PatchReprojectionMask(error_threshold=0.0)


# --- masked depth losses ---------------------------------------------------------------------------------------

Z_MAIN = [1.0, 2.0, 3.0, 4.0]
Z_OTHER = [3.0, 1.0, 5.0, 2.0]
MASK = [1.0, -1.0, 0.0, 1.0]


def loss_and_grads(mask: torch.Tensor | None, direction: str) -> tuple[float, list[float], list[float]]:
    z_main = torch.tensor(Z_MAIN, requires_grad=True)
    z_other = torch.tensor(Z_OTHER, requires_grad=True)
    loss = masked_depth_loss(z_main, z_other, mask, direction)
    loss.backward()
    # No gradient path at all (None) is as good as a zero gradient.
    grads = [[0.0] * 4 if z.grad is None else z.grad.tolist() for z in (z_main, z_other)]
    return float(loss.detach()), *grads


def test_bidirectional_loss_routes_gradients_by_the_mask():
    # Per-ray terms: +1 -> (1-3)^2 = 4 (to main), -1 -> (2-1)^2 = 1 (to other), 0 -> 0, +1 -> (4-2)^2 = 4;
    # averaged over all 4 rays.
    loss, g_main, g_other = loss_and_grads(torch.tensor(MASK), "bidirectional")
    assert loss == pytest.approx(9 / 4)
    assert g_main == pytest.approx([2 * (1 - 3) / 4, 0.0, 0.0, 2 * (4 - 2) / 4])
    assert g_other == pytest.approx([0.0, -2 * (2 - 1) / 4, 0.0, 0.0])


def test_one_way_loss_ignores_minus_one_rays():
    loss, g_main, g_other = loss_and_grads(torch.tensor(MASK), "one_way")
    assert loss == pytest.approx(8 / 4)
    assert g_main == pytest.approx([-1.0, 0.0, 0.0, 1.0])
    assert g_other == [0.0, 0.0, 0.0, 0.0]
    only_minus, g_main, g_other = loss_and_grads(torch.tensor([-1.0, -1.0, 0.0, 0.0]), "one_way")
    assert only_minus == 0.0 and g_main == [0.0] * 4 and g_other == [0.0] * 4


def test_trust_all_gives_gradient_to_both():
    z = torch.zeros(4)
    mask = TrustAll()(*context(Views(torch.zeros(2, 8, 8, 3), torch.eye(3).expand(2, 3, 3), cameras_at(
        [[0.0, 0, 0], [1.0, 0, 0]]), ["a", "b"]), {"view": z.long(), "uv": z[:, None].expand(4, 2).long(),
        "origins": z[:, None].expand(4, 3), "directions": z[:, None].expand(4, 3)}), z, z)  # fmt: skip
    assert mask is None
    loss, g_main, g_other = loss_and_grads(mask, "bidirectional")
    assert loss == pytest.approx((4 + 1 + 4 + 4) / 4)
    assert g_main == pytest.approx([-1.0, 0.5, -1.0, 1.0])
    assert g_other == pytest.approx([1.0, -0.5, 1.0, -1.0])


def test_limited_square_is_the_square_up_to_the_limit_and_linear_past_it():
    error = torch.tensor([-3.0, -1.0, 0.5, 1.0, 10.0], requires_grad=True)
    assert limited_square(error, None).tolist() == [9.0, 1.0, 0.25, 1.0, 100.0]
    limited = limited_square(error, 1.0)
    assert limited.tolist() == [5.0, 1.0, 0.25, 1.0, 19.0]  # 1 * (2 |e| - 1) past 1: continuous at the limit
    limited.sum().backward()
    assert error.grad.tolist() == [-2.0, -2.0, 1.0, 2.0, 2.0]  # the gradient of one ray is at most 2 * limit


def test_a_limit_bounds_the_masked_loss_of_a_ray_whose_depth_ran_away():
    z_main = torch.tensor([1.0, 2.0, 3.0, 4.0], requires_grad=True)
    z_other = torch.tensor([3.0, 1.0, 5.0, 102.0])  # ray 4: the other depth near the far plane
    loss = masked_depth_loss(z_main, z_other, torch.tensor([1.0, 1.0, 0.0, 1.0]), "one_way", limit=2.0)
    assert loss.item() == pytest.approx((4.0 + 1.0 + 0.0 + 2.0 * (2 * 98 - 2)) / 4)  # squared: (4 + 1 + 98^2) / 4
    loss.backward()
    assert z_main.grad.tolist() == pytest.approx([-1.0, 0.5, 0.0, -1.0])


def test_masked_loss_stays_finite_for_non_finite_masked_out_depths():
    z_main = torch.tensor([1.0, math.inf], requires_grad=True)
    loss = masked_depth_loss(z_main, torch.tensor([2.0, 0.0]), torch.tensor([1.0, 0.0]), "bidirectional")
    assert loss.item() == pytest.approx(0.5)


def test_unknown_direction_and_fractions():
    with pytest.raises(ValueError, match="direction"):
        masked_depth_loss(torch.zeros(2), torch.zeros(2), torch.zeros(2), "both")  # type: ignore[arg-type]
    fractions = mask_fractions(torch.tensor(MASK))
    assert {k: float(v) for k, v in fractions.items()} == {"plus": 0.5, "minus": 0.25, "zero": 0.25}
