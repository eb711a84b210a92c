"""The K-Planes grid field: exact interpolation, where gradients go, its simplified variants and its regulariser."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml

from simplenerf.model.fields import Field
from simplenerf.model.grid import KPlanesField, plane_tv, sample_plane, split_points, trunc_exp
from simplenerf.model.rendering import compute_weights
from simplenerf.model.samples import Samples
from tests.conftest import REPO
from tests.data.test_realestate import write_clip
from tests.run.test_cli import run


def node(index: int, nodes: int) -> float:
    """NDC coordinate of node `index` of an axis with `nodes` nodes (align_corners: -1 and +1 are the end nodes)."""
    return -1.0 + 2.0 * index / (nodes - 1)


def samples_at(positions: torch.Tensor, directions: torch.Tensor | None = None) -> Samples:
    """Samples at NDC points [R, S, 3] (the other fields of `Samples` do not matter to a field)."""
    r, s = positions.shape[:2]
    if directions is None:
        directions = torch.randn(r, 3, generator=torch.Generator().manual_seed(1))
    directions = torch.nn.functional.normalize(directions, dim=-1)
    zeros = torch.zeros(r, s)
    return Samples(t=zeros, t_metric=zeros, delta=zeros, positions=positions, directions=directions)


def test_interpolation_at_nodes_returns_node_values_and_is_bilinear_between():
    plane = torch.randn(1, 4, 5, 7, generator=torch.Generator().manual_seed(0))  # C=4, H=5 (height axis), W=7
    rows, cols = torch.meshgrid(torch.arange(5), torch.arange(7), indexing="ij")
    coords = torch.stack([cols.flatten() / 6 * 2 - 1, rows.flatten() / 4 * 2 - 1], dim=-1)  # (width, height)
    torch.testing.assert_close(sample_plane(plane, coords), plane[0].reshape(4, -1), rtol=0, atol=1e-6)
    # The centre of cell (row 1..2, col 3..4) is the mean of its four corners; a point a quarter of the way along
    # the width axis from node (2, 3) is 3/4 of that node plus 1/4 of its right neighbour.
    centre = torch.tensor([[(node(3, 7) + node(4, 7)) / 2, (node(1, 5) + node(2, 5)) / 2]])
    expected = plane[0, :, 1:3, 3:5].mean(dim=(1, 2))
    torch.testing.assert_close(sample_plane(plane, centre)[:, 0], expected, rtol=0, atol=1e-6)
    quarter = torch.tensor([[0.75 * node(3, 7) + 0.25 * node(4, 7), node(2, 5)]])
    torch.testing.assert_close(sample_plane(plane, quarter)[:, 0], 0.75 * plane[0, :, 2, 3] + 0.25 * plane[0, :, 2, 4],
                               rtol=0, atol=1e-6)
    # Outside the box: the border value.
    torch.testing.assert_close(sample_plane(plane, torch.tensor([[5.0, -3.0]]))[:, 0], plane[0, :, 0, 6])


def test_split_points_cuts_a_plane_no_larger_than_the_points_into_one_entry_per_thread(two_threads):
    small, large = torch.zeros(1, 4, 8, 16), torch.zeros(1, 4, 64, 64)  # 128 and 4096 nodes
    assert split_points(small, 1000) == 2
    assert split_points(large, 1000) == 1  # the summed per-thread gradients would cost more than they save
    assert split_points(small, 3) == 1  # fewer points than two per thread
    torch.set_num_threads(1)
    assert split_points(small, 1000) == 1


@pytest.mark.parametrize("points", [1000, 1001])  # 1001: one point repeated to fill the second entry
def test_sampling_split_among_threads_gives_the_same_values_and_gradients(two_threads, points):
    generator = torch.Generator().manual_seed(0)
    plane = torch.rand(1, 4, 8, 16, generator=generator, requires_grad=True)
    coords = torch.rand(points, 2, generator=generator) * 2.4 - 1.2  # some outside the box: border values
    weights = torch.rand(4, points, generator=generator)
    split = sample_plane(plane, coords)
    (split_grad,) = torch.autograd.grad((split * weights).sum(), plane)
    torch.set_num_threads(1)
    whole = sample_plane(plane, coords)
    (whole_grad,) = torch.autograd.grad((whole * weights).sum(), plane)
    assert split.shape == (4, points)
    assert torch.equal(split, whole)  # each point's interpolation is computed alone either way
    torch.testing.assert_close(split_grad, whole_grad, rtol=1e-6, atol=1e-6)  # the same terms, summed in another order


def test_features_at_grid_nodes_are_the_product_of_the_three_planes_node_values():
    field = KPlanesField(resolutions=[5], depth_resolutions=[3], features=4)
    xy, xz, yz = (p.detach()[0] for p in field.planes)  # [C, y, x], [C, z, x], [C, z, y]
    assert xy.shape == (4, 5, 5) and xz.shape == (4, 3, 5) and yz.shape == (4, 3, 5)
    points = torch.tensor([[node(a, 5), node(b, 5), node(c, 3)] for a, b, c in [(0, 0, 0), (1, 3, 2), (4, 2, 1)]])
    expected = torch.stack([xy[:, b, a] * xz[:, c, a] * yz[:, c, b] for a, b, c in [(0, 0, 0), (1, 3, 2), (4, 2, 1)]])
    torch.testing.assert_close(field.grid_features(points), expected, rtol=1e-6, atol=1e-7)


def test_extent_stretches_the_planes_over_a_wider_box_and_only_past_it_are_values_constant():
    box = KPlanesField(resolutions=[5], depth_resolutions=[3], features=4)
    wide = KPlanesField(resolutions=[5], depth_resolutions=[3], features=4, extent=(1.5, 1.67))
    wide.load_state_dict(box.state_dict())  # the same planes; only where their nodes sit differs
    points = torch.tensor([[0.3, -0.7, 0.2], [-1.0, 1.0, -0.5], [0.9, 0.1, 0.9]])
    stretched = points * torch.tensor([1.5, 1.67, 1.0])
    torch.testing.assert_close(wide.grid_features(stretched), box.grid_features(points), rtol=1e-6, atol=1e-7)
    # past x = 1 the unit box is constant along x (a streak); the wide box still varies until x = 1.5
    along_x = torch.tensor([[1.0, 0.2, 0.1], [1.2, 0.2, 0.1], [1.45, 0.2, 0.1], [1.5, 0.2, 0.1], [1.9, 0.2, 0.1]])
    assert torch.equal(box.grid_features(along_x)[1], box.grid_features(along_x)[0])
    outside = wide.grid_features(along_x)
    assert not torch.allclose(outside[1], outside[0]) and not torch.allclose(outside[2], outside[1])
    torch.testing.assert_close(outside[4], outside[3], rtol=1e-6, atol=1e-7)
    assert "extent=(1.5, 1.67)" in repr(wide)
    with pytest.raises(ValueError, match="extent"):
        KPlanesField(resolutions=[5], extent=(1.5, 0.0))


def test_gradients_reach_exactly_the_corners_of_the_cells_around_a_point():
    field = KPlanesField(resolutions=[9], depth_resolutions=[5], features=3)
    # Inside x cell 2..3 (of 9 nodes), y cell 5..6, z cell 1..2 (of 5 nodes).
    point = torch.tensor([[(node(2, 9) + 0.3 * 0.25), (node(5, 9) + 0.6 * 0.25), (node(1, 5) + 0.2 * 0.5)]])
    field.grid_features(point).sum().backward()
    cells = {"xy": ([5, 6], [2, 3]), "xz": ([1, 2], [2, 3]), "yz": ([1, 2], [5, 6])}  # (height nodes, width nodes)
    for plane, (rows, cols) in zip(field.planes, cells.values(), strict=True):
        touched = plane.grad[0].abs().sum(0) > 0  # [H, W]
        expected = torch.zeros_like(touched)
        expected[rows[0] : rows[1] + 1, cols[0] : cols[1] + 1] = True
        assert torch.equal(touched, expected)


def test_points_augmentation_is_the_same_field_with_its_coarsest_scales_only():
    main = KPlanesField(resolutions=[16, 32, 64], depth_resolutions=[8, 16, 32], features=4)
    simple = KPlanesField(resolutions=[16], depth_resolutions=[8], features=4)
    plane_params = lambda f: sum(p.numel() for p in f.parameter_groups()["grid"])  # noqa: E731
    assert plane_params(main) == 4 * ((16 * 16 + 2 * 16 * 8) + (32 * 32 + 2 * 32 * 16) + (64 * 64 + 2 * 64 * 32))
    assert plane_params(simple) == 4 * (16 * 16 + 2 * 16 * 8)  # 42x fewer grid parameters
    assert [tuple(p.shape) for p in simple.planes] == [tuple(p.shape) for p in main.planes[:3]]
    # With the same coarsest planes, its features are the main field's first-scale features.
    with torch.no_grad():
        for mine, theirs in zip(simple.planes, main.planes[:3], strict=False):
            mine.copy_(theirs)
    points = torch.rand(10, 3) * 2 - 1
    torch.testing.assert_close(simple.grid_features(points), main.grid_features(points)[:, :4])


def test_fewer_density_features_give_a_lower_rank_density_and_pass_the_rest_to_the_colour():
    # Simple-TensoRF's points augmentation: 4 density components instead of 16, the colour's unchanged.
    full = KPlanesField(resolutions=[16], depth_resolutions=[8], features=8, hidden=32, geometry_features=15)
    low = KPlanesField(resolutions=[16], depth_resolutions=[8], features=8, density_features=2,
                       residual_scales_to_color=True, hidden=32, geometry_features=15)
    assert [tuple(p.shape) for p in low.planes] == [tuple(p.shape) for p in full.planes]  # the same planes
    assert (full.density_net[0].in_features, low.density_net[0].in_features) == (8, 2)
    assert (full.color_net[0].in_features, low.color_net[0].in_features) == (15 + 27, 15 + 6 + 27)
    count = lambda m: sum(p.numel() for p in m.parameters())  # noqa: E731
    assert count(full.density_net) - count(low.density_net) == 6 * 32  # 6 fewer inputs to the 32 hidden units
    # Two scales, 3 of 4 channels of the coarser one to the density: the rest is that scale's channel 3, then the
    # finer scale (scale-major).
    two = KPlanesField(resolutions=[4, 8], features=4, density_scales=1, density_features=3,
                       residual_scales_to_color=True)
    features = torch.arange(8.0).expand(2, 8)  # [P, C scales]
    seen, rest = two.split_features(features)
    assert seen[0].tolist() == [0.0, 1.0, 2.0] and rest[0].tolist() == [3.0, 4.0, 5.0, 6.0, 7.0]
    assert two.color_net[0].in_features == 15 + 5 + 27
    # Changing the channels beyond density_features changes the colour only.
    torch.manual_seed(0)
    samples = samples_at(torch.rand(3, 4, 3) * 2 - 1)
    before = low(samples)
    with torch.no_grad():
        for plane in low.planes:
            plane[:, 2:] += 0.3
    after = low(samples)
    assert torch.equal(before.raw_density, after.raw_density) and not torch.allclose(before.rgb, after.rgb)
    with pytest.raises(ValueError, match="would be unused"):
        KPlanesField(resolutions=[8], features=8, density_features=4)
    with pytest.raises(ValueError, match="density_features must be in"):
        KPlanesField(resolutions=[8], features=8, density_features=9, residual_scales_to_color=True)


def test_view_independent_field_ignores_directions_and_the_main_one_does_not():
    torch.manual_seed(0)
    positions = torch.rand(3, 4, 3) * 2 - 1
    d1 = torch.nn.functional.normalize(torch.randn(3, 3), dim=-1)
    d2 = torch.nn.functional.normalize(torch.randn(3, 3), dim=-1)
    views = KPlanesField(resolutions=[8], features=4, view_dependent=False)
    a, b = views(samples_at(positions, d1)), views(samples_at(positions, d2))
    assert torch.equal(a.rgb, b.rgb) and torch.equal(a.raw_density, b.raw_density)
    assert views.color_net[0].in_features == 15  # the geometry feature only
    main = KPlanesField(resolutions=[8], features=4)
    a, b = main(samples_at(positions, d1)), main(samples_at(positions, d2))
    assert torch.equal(a.raw_density, b.raw_density) and not torch.allclose(a.rgb, b.rgb)


def test_outputs_follow_the_field_contract():
    field = KPlanesField(resolutions=[8, 16], features=4)
    assert isinstance(field, Field)
    out = field(samples_at(torch.rand(5, 6, 3) * 2 - 1))
    assert out.raw_density.shape == (5, 6) and out.rgb.shape == (5, 6, 3)
    assert bool((out.raw_density > 0).all())  # trunc_exp: the NeRF's ReLU leaves it as is
    assert bool(((out.rgb > 0) & (out.rgb < 1)).all())


def test_parameter_groups_split_grids_from_decoders():
    field = KPlanesField(resolutions=[8, 16], features=4)
    groups = field.parameter_groups()
    assert set(groups) == {"grid", "decoder"}
    assert len(groups["grid"]) == 6 and all(p.dim() == 4 for p in groups["grid"])
    ids = [id(p) for ps in groups.values() for p in ps]
    assert sorted(ids) == sorted(id(p) for p in field.parameters())  # a partition of all parameters


def test_plane_tv_gradient_is_that_of_its_formula():
    plane = torch.rand(1, 3, 5, 7, generator=torch.Generator().manual_seed(0), dtype=torch.float64,
                       requires_grad=True)
    formula = 2.0 * (torch.square(plane[..., 1:, :] - plane[..., :-1, :]).mean()
                     + torch.square(plane[..., :, 1:] - plane[..., :, :-1]).mean())
    (expected,) = torch.autograd.grad(3.0 * formula, plane)
    (grad,) = torch.autograd.grad(3.0 * plane_tv(plane), plane)
    torch.testing.assert_close(plane_tv(plane), formula, rtol=1e-12, atol=0)
    torch.testing.assert_close(grad, expected, rtol=1e-12, atol=1e-15)
    # by hand at a corner node (0, 0), the - end of one difference along each axis: 3 * 4 / n * -(d_h + d_w)
    d_h, d_w = (plane[0, :, 1, 0] - plane[0, :, 0, 0]).detach(), (plane[0, :, 0, 1] - plane[0, :, 0, 0]).detach()
    torch.testing.assert_close(grad[0, :, 0, 0], -12.0 * (d_h / (3 * 4 * 7) + d_w / (3 * 5 * 6)), rtol=1e-12, atol=0)


def test_regularization_is_the_total_variation_of_the_planes_with_its_weight_apart():
    field = KPlanesField(resolutions=[4], depth_resolutions=[3], features=2, tv_weight=0.5, depth_tv_scale=0.25)
    with torch.no_grad():
        for p in field.planes:
            p.fill_(1.0)
        field.planes[0].copy_(torch.arange(4.0).expand(1, 2, 4, 4))  # +1 per node along x: TV = 2 (1 + 0)
        field.planes[1][..., 1, :] = 3.0  # xz: a ridge along z: differences 2, -2 on 2 of 2 rows -> 2 (4 + 0)
    assert plane_tv(field.planes[0]).item() == pytest.approx(2.0)
    assert plane_tv(field.planes[1]).item() == pytest.approx(8.0)
    assert field.regularization("tv").item() == pytest.approx(2.0 + 0.25 * 8.0)  # xy + scale * (xz + yz)
    assert field.regularizers() == {"tv": 0.5}  # the weight is the objective's term weight
    with pytest.raises(KeyError, match="no regulariser 'l1'"):
        field.regularization("l1")


def test_trunc_exp_clamps_its_gradient_only():
    x = torch.tensor([0.0, 2.0, 20.0], requires_grad=True)
    y = trunc_exp(x)
    torch.testing.assert_close(y, torch.exp(x.detach()))
    y.sum().backward()
    torch.testing.assert_close(x.grad, torch.exp(torch.tensor([0.0, 2.0, 15.0])))


def test_trunc_exp_of_a_huge_input_is_finite_so_a_zero_interval_has_zero_weight():
    x = torch.tensor([[1.0, 100.0, 100.0]], requires_grad=True)  # exp(100) overflows float32
    sigma = trunc_exp(x)
    assert bool(torch.isfinite(sigma).all()) and sigma[0, 1] > torch.finfo(sigma.dtype).max / 3
    weights = compute_weights(sigma, torch.tensor([[0.5, 0.0, 0.5]]))  # the dense point on a zero-length interval
    assert bool(torch.isfinite(weights).all()) and weights[0, 1] == 0.0
    weights.sum().backward()
    assert bool(torch.isfinite(x.grad).all())


def test_bad_sizes_are_errors():
    with pytest.raises(ValueError, match="one depth resolution per scale"):
        KPlanesField(resolutions=[8, 16], depth_resolutions=[8])
    with pytest.raises(ValueError, match="at least 2 nodes"):
        KPlanesField(resolutions=[1])


# The grid configs through the real command line (a few steps each; files in a tmp folder).

GRID = REPO / "configs" / "grid"
FEW_STEPS = ["--trainer.max_steps", "2", "--trainer.val_check_interval", "2", "--checkpoint.every_n_train_steps", "2",
             "--data.init_args.rays_per_batch", "64", "--model.chunk", "4096"]


def run_dirs(tmp: Path, name: str) -> list[str]:
    out = str(tmp / name)
    return ["--trainer.default_root_dir", out, "--trainer.logger.init_args.save_dir", out]


@pytest.fixture(scope="module")
def grid_demo(tmp_path_factory) -> Path:
    """2 steps of the grid demo (SimpleNeRF, K-Planes, the "objects" scene with SfM depth), then `test`."""
    tmp = tmp_path_factory.mktemp("grid_demo")
    args = ["--config", str(GRID / "demo.yaml"), *FEW_STEPS, "--data.init_args.sparse_rays_per_batch", "32",
            "--data.init_args.root", str(tmp / "data"), "--data.init_args.sparse_depth_cache", str(tmp / "cache"),
            *run_dirs(tmp, "run")]
    run("fit", *args)
    run("test", *args, "--ckpt_path", "last", "--evaluation.lpips", "false")
    return tmp


def test_grid_demo_trains_grids_and_tests_through_the_cli(grid_demo):
    last = torch.load(grid_demo / "run" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 2
    state = last["state_dict"]
    assert state["nerf.fine.planes.6"].shape == (1, 16, 128, 128)  # the finest scale's xy plane
    assert state["augmentations.0.field.planes.0"].shape == (1, 8, 32, 32)  # points: the coarsest scale only
    assert "augmentations.0.field.planes.3" not in state
    assert state["augmentations.1.field.color_net.0.weight"].shape[1] == 15  # views: no direction input
    # Adam kept one learning rate per parameter group: the planes' and the decoders'.
    groups = {g["name"]: g["lr"] for g in last["optimizer_states"][0]["param_groups"]}
    assert groups["grid"] > groups["decoder"]
    summary = json.loads((grid_demo / "run" / "test" / "summary.json").read_text())
    assert 0 < summary["psnr"] < 100 and summary["depth_mae"] >= 0  # the scene's exact depth is the reference
    assert (grid_demo / "data" / "objects_seed0_96x128_20" / "depths").is_dir()


def test_grid_demo_dsnerf_fits(grid_demo):
    args = ["--config", str(GRID / "demo_dsnerf.yaml"), *FEW_STEPS, "--data.init_args.sparse_rays_per_batch", "32",
            "--data.init_args.root", str(grid_demo / "data"),
            "--data.init_args.sparse_depth_cache", str(grid_demo / "cache"), *run_dirs(grid_demo, "dsnerf")]
    run("fit", *args)
    last = torch.load(grid_demo / "dsnerf" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 2 and not any(k.startswith("augmentations.") for k in last["state_dict"])


@pytest.mark.parametrize("config", ["simplenerf", "simplerf"])
def test_llff_grid_config_fits_on_an_llff_scene(synthetic_scene, tmp_path, config):
    """The LLFF grid configs on the generated LLFF-layout scene (factor 1, 48x64, 2 views; SfM needs more pixels).
    Their DS-NeRF twin is the same config without the simplifiers (checked below)."""
    run("fit", "--config", str(GRID / f"{config}.yaml"), "--config", str(REPO / "configs/overrides/views/2.yaml"),
        *FEW_STEPS, "--data.init_args.scene_dir", str(synthetic_scene), "--data.init_args.factor", "1",
        "--data.init_args.sparse_rays_per_batch", "0", *run_dirs(tmp_path, "run"))
    last = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    planes = [k for k in last["state_dict"] if k.startswith("nerf.fine.planes.")]
    assert last["global_step"] == 2 and len(planes) == 9  # 3 scales x (xy, xz, yz)
    assert last["state_dict"]["nerf.fine.planes.6"].shape == (1, 16, 256, 256)  # the finest xy plane


def test_realestate_grid_config_fits_on_a_clip(tmp_path):
    scene, _ = write_clip(tmp_path / "clips")
    run("fit", "--config", str(GRID / "realestate_simplenerf.yaml"),
        "--config", str(REPO / "configs/overrides/views/3.yaml"), *FEW_STEPS, "--data.init_args.scene_dir", str(scene),
        "--data.init_args.sparse_rays_per_batch", "0", *run_dirs(tmp_path, "run"))
    last = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 2


@pytest.mark.parametrize(("simple", "baseline"), [("demo", "demo_dsnerf"), ("simplenerf", "dsnerf"),
                                                  ("simplerf", "dsnerf"), ("simplerf_images4", "dsnerf_images4"),
                                                  ("realestate_simplenerf", "realestate_dsnerf")])
def test_grid_dsnerf_configs_are_the_simplenerf_ones_without_the_simplifiers(simple, baseline):
    a = yaml.safe_load((GRID / f"{simple}.yaml").read_text())
    b = yaml.safe_load((GRID / f"{baseline}.yaml").read_text())
    assert len(a["model"]["augmentations"]) == 2 and b["model"]["augmentations"] == []
    assert b["model"]["objective"]["coarse_fine_mask"] is None
    # the baseline schedules what both have (the distortion loss, the colour spread, the depth smoothness), exactly as
    # SimpleNeRF does
    schedules_a = a["trainer"]["callbacks"][0]["init_args"]["schedules"]
    schedules_b = {name: points for callback in b["trainer"].get("callbacks", [])
                   for name, points in callback["init_args"]["schedules"].items()}
    shared = ("_distortion", "_color_spread", "_depth_smoothness")
    assert schedules_b == {name: points for name, points in schedules_a.items() if name.endswith(shared)}
    for key in ("max_steps", "val_check_interval", "limit_val_batches"):
        assert a["trainer"].get(key) == b["trainer"].get(key)
    for config in (a, b):
        config["model"].pop("augmentations")
        for key in ("coarse_fine_mask", "coarse_fine_weight", "coarse_fine_on_sparse_rays", "supervision",
                    "depth_loss_space", "depth_error_limit"):  # what only the masked depth losses read
            config["model"]["objective"].pop(key, None)
        config.pop("trainer")
    assert a == b


def test_density_only_samples_give_the_same_density_without_colour():
    torch.manual_seed(0)
    field = KPlanesField(resolutions=[4, 8], features=4, hidden=8)
    positions = torch.rand(3, 5, 3) * 2 - 1
    full = field(samples_at(positions))
    samples = samples_at(positions)
    samples.color = False
    only = field(samples)
    assert only.rgb is None and torch.equal(only.raw_density, full.raw_density)
