"""The LightningModule's loss composition (paper Sec. 4.4) on real data-module batches."""

from types import SimpleNamespace

import pytest
import torch

from simplenerf.data.batches import TrainingBatch
from simplenerf.data.synthetic import SyntheticDataModule
from simplenerf.method.module import SimpleNeRF
from simplenerf.method.objective import Objective, RenderedRays
from simplenerf.method.reliability import ReliabilityMask
from simplenerf.model.nerf import mlp_nerf


@pytest.fixture(scope="module")
def datamodule(tmp_path_factory):
    """The synthetic scene at 240x320 (SIFT needs the pixels), 2 views, with sparse depth."""
    tmp = tmp_path_factory.mktemp("module")
    dm = SyntheticDataModule(root=str(tmp / "data"), height=240, width=320, n_frames=8, n_views=2, rays_per_batch=64,
                             sparse_rays_per_batch=16, sparse_depth_cache=str(tmp / "cache"))
    dm.setup("fit")
    return dm


@pytest.fixture(scope="module")
def batch(datamodule):
    return next(iter(datamodule.train_dataloader()))


def module(**objective) -> SimpleNeRF:
    torch.manual_seed(0)
    return SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, num_layers=2, width=16, skip_layer=1),
                      objective=Objective(**objective))


def step(model: SimpleNeRF, batch: TrainingBatch, monkeypatch) -> tuple[torch.Tensor, dict]:
    """A training step without its optimiser: the parts backpropagated (gradients in `.grad`); the total loss and
    what the step logs."""
    logged = {}
    monkeypatch.setattr(model, "log_dict", lambda values, **kw: logged.update(values))
    monkeypatch.setattr(model, "log", lambda *a, **kw: None)
    result = model.backward_parts(batch, torch.Tensor.backward)
    model.log_step(result, batch)
    return result.loss, logged


def test_loss_is_the_weighted_sum_of_its_terms(batch, monkeypatch):
    model = module(color_weight=1.0, sparse_depth_weight=0.1)
    loss, logged = step(model, batch, monkeypatch)
    expected = logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"]
    assert torch.allclose(loss, expected)
    assert logged["train/loss_sparse_depth"] > 0
    assert logged["train_params/color"] == 1.0 and logged["train_params/sparse_depth"] == 0.1  # the weights too


def test_sparse_depth_loss_trains_fine_not_coarse(batch, monkeypatch):
    model = module(color_weight=0.0, sparse_depth_weight=1.0)
    _, logged = step(model, batch, monkeypatch)
    assert "train/loss_color" not in logged  # a term of weight 0 is not computed
    assert model.nerf.fine.trunk[0].weight.grad.abs().sum() > 0
    coarse_grad = model.nerf.coarse.trunk[0].weight.grad
    assert coarse_grad is None or coarse_grad.abs().sum() == 0


def test_without_sparse_rays_only_colour_counts(batch, monkeypatch):
    loss, logged = step(module(), TrainingBatch(batch.random), monkeypatch)
    assert "train/loss_sparse_depth" not in logged and torch.allclose(loss, logged["train/loss_color"])


def simplenerf_module(supervision: str = "bidirectional", rays_per_backward: int | None = None) -> SimpleNeRF:
    from simplenerf.method.augmentations import Augmentation
    from simplenerf.method.reliability import PatchReprojectionMask
    from simplenerf.model.fields import RadianceField

    torch.manual_seed(0)
    size = {"num_layers": 2, "width": 16, "skip_layer": 1}
    augs = [
        Augmentation("points", RadianceField(density_bands=3, residual_bands_to_color=True, **size),
                     PatchReprojectionMask(error_threshold=1.0)),
        Augmentation("views", RadianceField(view_dependent=False, **size), PatchReprojectionMask(error_threshold=1.0)),
    ]
    objective = Objective(coarse_fine_mask=PatchReprojectionMask(error_threshold=1.0), supervision=supervision)
    return SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, **size), augmentations=augs, objective=objective,
                      rays_per_backward=rays_per_backward)


class FineMoreReliable(ReliabilityMask):
    """A mask of -1 on every ray: for L_cfc, the fine depth is the more reliable one (bypasses the reprojection)."""

    def __call__(self, views, rays, z_main, z_other):
        return -torch.ones_like(z_main)


@pytest.mark.parametrize("cfc_direction", [None, "one_way", "bidirectional"])
def test_coarse_fine_supervision_sets_the_direction_of_l_cfc_alone(batch, cfc_direction):
    objective = Objective(coarse_fine_mask=FineMoreReliable(), supervision="bidirectional",
                          coarse_fine_supervision=cfc_direction)
    model = SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, num_layers=2, width=16, skip_layer=1), objective=objective)
    expected = cfc_direction or "bidirectional"
    assert model.terms["cfc"].supervision == expected
    renders = model.render(batch.random.rays, randomized=False)
    rendered = RenderedRays("random", batch.random, renders, share=1.0, errors=SimpleNamespace(views=None, rays=None))
    value = model.terms["cfc"].value(rendered).value
    fine, coarse = renders.main.fine.depth, renders.main.coarse.depth
    g_fine, g_coarse = torch.autograd.grad(value, [fine, coarse], allow_unused=True)
    # Every ray -1: the bidirectional loss trains the fine depth toward the coarse one, the one-way loss nothing.
    if expected == "one_way":
        assert value.item() == 0.0 and (g_fine is None or not g_fine.any())
    else:
        torch.testing.assert_close(value, (coarse.detach() - fine).square().mean())
        torch.testing.assert_close(g_fine, 2 * (fine - coarse).detach() / fine.numel())
    assert g_coarse is None or not g_coarse.any()  # never toward the fine depth where it is the less reliable


def deterministic(model: SimpleNeRF, monkeypatch) -> None:
    """The model's training renders made deterministic (no jitter, no noise)."""
    render = model.render
    monkeypatch.setattr(model, "render", lambda rays, randomized, color=True, skip=frozenset(): render(
        rays, False, color, skip))


def run_step(model, dm, monkeypatch) -> tuple[torch.Tensor, dict]:
    model.set_train_views(dm.train_views)
    return step(model, next(iter(dm.train_dataloader())), monkeypatch)


def test_masked_losses_cost_nothing_before_the_warm_up(datamodule, monkeypatch):
    from simplenerf.method import reliability

    model = simplenerf_module()
    for name in ("points", "views", "cfc"):
        model.terms[name].weight = 0.0
    calls = []
    original = reliability.ReprojectionErrors.__call__
    monkeypatch.setattr(reliability.ReprojectionErrors, "__call__",
                        lambda self, *a: calls.append(1) or original(self, *a))
    loss, logged = run_step(model, datamodule, monkeypatch)
    assert calls == []  # no mask computed
    assert {"train/loss_points", "train/loss_views", "train/loss_cfc"}.isdisjoint(logged)
    assert torch.allclose(loss, logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"])


def test_all_paper_losses_after_the_warm_up(datamodule, monkeypatch):
    model = simplenerf_module()
    loss, logged = run_step(model, datamodule, monkeypatch)
    terms = ["color", "sparse_depth", "points", "views", "cfc"]
    weights = {"color": 1.0, "sparse_depth": 0.1, "points": 0.1, "views": 0.1, "cfc": 0.1}
    assert torch.allclose(loss, sum(weights[t] * logged[f"train/loss_{t}"] for t in terms))
    for name in ("points", "views", "cfc"):
        fractions = [logged[f"train/mask_{name}/{k}"] for k in ("plus", "minus", "zero")]
        assert torch.allclose(sum(fractions), torch.tensor(1.0))
    for aug in model.augmentations:  # the augmented fields are trained (colour, L_sd and their masked loss)
        assert aug.field.trunk[0].weight.grad.abs().sum() > 0


def test_the_coarse_sparse_depth_term_is_l_sd_on_the_main_coarse_depth_alone(datamodule, monkeypatch):
    """`coarse_sparse_depth_weight` adds DS-NeRF's L_sd on the main coarse depth ("coarse_sparse_depth"): its value
    is mean(weight * (z_coarse - z_sfm)^2) over the sparse rays, none of the fine or augmented depths, and it is in
    the step's loss with its weight; at its default 0 it is not computed."""
    from types import SimpleNamespace

    from simplenerf.method.objective import SparseDepthTerm

    def render(*depths: float) -> SimpleNamespace:
        return SimpleNamespace(depth=torch.tensor(depths))

    renders = SimpleNamespace(main=SimpleNamespace(coarse=render(1.0, 2.0, 4.0), fine=render(9.0, 9.0, 9.0)),
                              augmented={"points": render(7.0, 7.0, 7.0)})
    rays = SimpleNamespace(depth=torch.tensor([1.0, 1.0, 2.0]), weight=torch.tensor([1.0, 1.0, 0.5]))
    term = SparseDepthTerm(0.1, coarse=True)
    assert term.name == "coarse_sparse_depth" and term.reads == ("sparse",)
    assert term.value(SimpleNamespace(renders=renders, rays=rays)).value.item() == pytest.approx((0 + 1 + 2) / 3)

    model = simplenerf_module()
    assert model.terms["coarse_sparse_depth"].weight == 0.0
    _, logged = run_step(model, datamodule, monkeypatch)
    assert "train/loss_coarse_sparse_depth" not in logged
    model = simplenerf_module()
    for name in ("points", "views", "cfc"):
        model.terms[name].weight = 0.0
    model.terms["coarse_sparse_depth"].weight = 0.1
    loss, logged = run_step(model, datamodule, monkeypatch)
    assert logged["train/loss_coarse_sparse_depth"] > 0
    assert torch.allclose(loss, logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"]
                          + 0.1 * logged["train/loss_coarse_sparse_depth"])


def test_augmentations_share_the_main_coarse_samples(datamodule, monkeypatch):
    model = simplenerf_module()
    seen = []
    for aug in model.augmentations:
        original = aug.field.forward
        monkeypatch.setattr(aug.field, "forward",
                            lambda s, f=original: seen.append((s, s.encoded_positions(10))) or f(s))
    original_coarse = model.nerf.coarse.forward
    monkeypatch.setattr(model.nerf.coarse, "forward",
                        lambda s: seen.append((s, s.encoded_positions(10))) or original_coarse(s))
    run_step(model, datamodule, monkeypatch)
    assert len(seen) == 3 and seen[1][0] is seen[0][0] and seen[2][0] is seen[0][0]  # the same samples
    assert seen[1][1].data_ptr() == seen[0][1].data_ptr() == seen[2][1].data_ptr()  # one encoding, computed once


def test_loss_weight_schedule_is_data():
    from simplenerf.run.callbacks import LossWeightSchedule

    schedule = LossWeightSchedule({"points": [(0, 0.0), (10000, 0.1)]})
    assert [schedule.value("points", s, 0.1) for s in (0, 9999, 10000, 50000)] == [0.0, 0.0, 0.1, 0.1]
    with pytest.raises(ValueError):
        LossWeightSchedule({"cfc": [(10, 0.1), (0, 0.0)]})


def test_an_augmentation_whose_own_terms_stay_off_is_retired_and_leaves_the_main_model_as_it_was(datamodule,
                                                                                                  monkeypatch):
    """From the step where an augmentation's masked depth term is 0 to the end of the schedule, training stops
    rendering it: its field gets no gradient, and the main model's gradient is the same to the bit (nothing the
    augmentation renders reaches the main model once its term is off)."""
    from simplenerf.run.callbacks import LossWeightSchedule

    schedule = LossWeightSchedule({"points": [(0, 0.1), (5, 0.0)]})
    model = simplenerf_module()
    for global_step, retired in ((4, set()), (5, {"points"}), (9, {"points"})):
        schedule.on_train_batch_start(SimpleNamespace(global_step=global_step), model, None, 0)
        assert model.retired == retired and model.terms["points"].weight == (0.0 if retired else 0.1)
    back_on = LossWeightSchedule({"points": [(0, 0.1), (5, 0.0), (8, 0.1)]})  # off for a while, then on again
    back_on.on_train_batch_start(SimpleNamespace(global_step=5), model, None, 0)
    assert model.retired == frozenset() and model.terms["points"].weight == 0.0

    grads = {}
    for retired in (frozenset(), frozenset({"points"})):
        model = simplenerf_module()
        model.terms["points"].weight = 0.0
        model.retired = retired
        deterministic(model, monkeypatch)  # both steps see the same samples
        _, logged = run_step(model, datamodule, monkeypatch)
        grads[retired] = {name: p.grad for name, p in model.named_parameters()}
    rendered, skipped = grads[frozenset()], grads[frozenset({"points"})]
    assert all(skipped[name] is None for name in skipped if name.startswith("augmentations.0."))
    assert all(rendered[name] is not None for name in rendered if name.startswith("augmentations.0."))
    main = [name for name in rendered if not name.startswith("augmentations.0.")]
    assert main and all(torch.equal(rendered[name], skipped[name]) for name in main)


def test_the_augmentations_a_schedule_retires_from_step_0_are_the_untrained_ones():
    """`untrained_augmentations`: those whose own terms the schedule holds at 0 from step 0 to the end (never
    rendered in training); a warm-up or a later retirement is not that, nor is a term left at its configured 0.1."""
    from simplenerf.run.callbacks import LossWeightSchedule, untrained_augmentations

    model = simplenerf_module()
    assert untrained_augmentations(model, []) == frozenset()
    ablation = LossWeightSchedule({"points": [(0, 0.0)], "views": [(0, 0.0)]})
    assert untrained_augmentations(model, [ablation]) == {"points", "views"}
    warm_up = LossWeightSchedule({"points": [(0, 0.0), (100, 0.1)]})  # views: not scheduled, its weight 0.1
    assert untrained_augmentations(model, [warm_up]) == frozenset()
    later = LossWeightSchedule({"points": [(0, 0.1), (1, 0.0)], "views": [(0, 0.0)]})  # points trained one step
    assert untrained_augmentations(model, [later]) == {"views"} and later.retired(model, 1) == {"points", "views"}
    assert model.terms["points"].weight == model.terms["views"].weight == 0.1  # asking changes no weight


def test_a_schedule_naming_an_unknown_loss_is_one_clear_error():
    from simplenerf.errors import SimpleNeRFError
    from simplenerf.run.callbacks import LossWeightSchedule

    model = simplenerf_module()
    LossWeightSchedule({"points": [(0, 0.0)], "cfc": [(0, 0.0)]}).check_model(model)  # known names pass
    known = ("cfc, coarse_color_spread, coarse_depth_smoothness, coarse_distortion, coarse_sparse_depth, color, "
             "fine_color_spread, fine_concentration, fine_depth_smoothness, fine_distortion, points")
    with pytest.raises(SimpleNeRFError, match=rf"schedules 'point', but the model's losses are {known}"):
        LossWeightSchedule({"point": [(0, 0.0)]}).check_model(model)


def test_reliability_maps_of_a_train_view(datamodule, monkeypatch):
    from simplenerf.viz.pictures import mask_picture

    model = simplenerf_module()
    model.hparams.chunk = 20000
    run_step(model, datamodule, monkeypatch)
    maps = model.reliability_maps(view=0)
    assert set(maps) == {"points", "views", "cfc"}
    for m in maps.values():
        assert m.shape == (240, 320) and set(m.unique().tolist()) <= {-1.0, 0.0, 1.0}
        assert bool((m[:2] == 0).all())  # within k // 2 of the border nothing is reliable
    picture = mask_picture(torch.tensor([[1.0, 0.0, -1.0]]))
    assert picture.shape == (1, 3, 3) and picture[0, :, 0].tolist() == [0, 128, 255]


def test_parts_give_the_one_part_loss_gradient_and_logs(datamodule, monkeypatch):
    """One part (the whole batch), random rays then sparse-depth rays whole (parts of 10^6 rays), and parts of at most
    23 rays (uneven here): the same total loss, gradient and logged terms and mask fractions (rendering made
    deterministic here, since the ways draw jitter and noise in a different order)."""
    results = []
    for rays_per_backward in (None, 10**6, 23):
        model = simplenerf_module(rays_per_backward=rays_per_backward)
        deterministic(model, monkeypatch)
        loss, logged = run_step(model, datamodule, monkeypatch)
        grads = torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None])
        results.append((loss, grads, {k: float(v) for k, v in logged.items()}))
    loss_a, grad_a, logged_a = results[0]
    assert {"train/loss_sparse_depth", "train/loss_cfc", "train/loss_points", "train/mask_cfc/plus"} <= set(logged_a)
    assert sum(logged_a[f"train/mask_views/{k}"] for k in ("plus", "minus", "zero")) == pytest.approx(1.0)
    for loss_b, grad_b, logged_b in results[1:]:
        assert torch.allclose(loss_a, loss_b, rtol=1e-5) and logged_a == pytest.approx(logged_b, rel=1e-5)
        assert grad_a.shape == grad_b.shape and torch.allclose(grad_a, grad_b, rtol=1e-4, atol=1e-7)


def test_batch_parts_split_random_then_sparse_rays_by_share(batch):
    from simplenerf.method.module import batch_parts

    whole = batch_parts(batch, None)
    assert len(whole) == 1 and whole[0].random is batch.random and whole[0].sparse is batch.sparse
    parts = batch_parts(batch, 24)  # 64 random rays, 16 sparse
    assert [(p.random is not None, p.sparse is not None) for p in parts] == [(True, False)] * 3 + [(False, True)]
    assert [p.random_share for p in parts[:3]] == [24 / 64, 24 / 64, 16 / 64] and parts[3].sparse_share == 1.0
    assert torch.equal(torch.cat([p.random.uv for p in parts[:3]]), batch.random.uv)


def test_the_main_coarse_reprojection_error_is_computed_once_per_part(datamodule, monkeypatch):
    from simplenerf.method import reliability

    model = simplenerf_module(rays_per_backward=40)  # random rays in 2 parts
    computed = []
    original = reliability._reprojection_error
    monkeypatch.setattr(reliability, "_reprojection_error", lambda *a, **k: computed.append(1) or original(*a, **k))
    judged = []
    judge = reliability.ReprojectionErrors.__call__
    monkeypatch.setattr(reliability.ReprojectionErrors, "__call__",
                        lambda self, name, *a: judged.append(name) or judge(self, name, *a))
    run_step(model, datamodule, monkeypatch)
    assert judged == ["coarse", "points", "coarse", "views", "coarse", "fine"] * 2  # three pairs judge main coarse
    assert len(computed) == 4 * 2  # its error once per part: coarse, points, views, fine


def test_ray_slices_cover_the_rays_in_parts_of_at_most_size():
    from simplenerf.method.module import ray_slices

    assert ray_slices(5, 2) == [slice(0, 2), slice(2, 4), slice(4, 5)]
    assert ray_slices(4, None) == [slice(0, 4)] and ray_slices(4, 8) == [slice(0, 4)]


@pytest.mark.parametrize("space,limit", [("metric", None), ("inverse", None), ("metric", 1.0)])
def test_masked_depth_losses_compare_metric_or_inverse_depth(space, limit):
    """`depth_loss_space`: the masked losses compare z or 1 / z; the mask itself always sees metric depth.
    `depth_error_limit`: past it a ray's error counts linearly."""
    from types import SimpleNamespace

    from simplenerf.method.objective import MaskedDepthTerm, RenderedRays
    from simplenerf.method.reliability import ReliabilityMask
    from simplenerf.model.rendering import RenderOutputs

    seen = {}

    class Stub(ReliabilityMask):  # does not look at the views
        def __call__(self, views, rays, z_main, z_other):
            seen["z"] = (z_main, z_other)
            return torch.tensor([1.0, -1.0, 0.0, 1.0])

    def render(depth):
        return RenderOutputs(None, torch.tensor(depth), torch.ones(4), torch.ones(4, 1))

    outputs = {"coarse": render([2.0, 4.0, 8.0, 1.0]), "points": render([4.0, 2.0, 100.0, 1.0])}
    renders = type("R", (), {"__getitem__": lambda self, name: outputs[name]})()
    term = MaskedDepthTerm("points", 0.1, Stub(), "coarse", "points", "bidirectional", space, depth_error_limit=limit)
    result = term.value(RenderedRays("random", None, renders, 1.0, SimpleNamespace(views=None, rays=None)))
    assert {k: v.item() for k, v in result.masks.items()} == {"plus": 0.5, "minus": 0.25, "zero": 0.25}
    assert seen["z"][0].tolist() == [2.0, 4.0, 8.0, 1.0]
    # rays with mask +1 and -1 count, the mask-0 ray (metric error 92) does not; the mean is over all 4 rays
    expected = (4.0 + 4.0 + 0.0 + 0.0) / 4 if space == "metric" else ((0.5 - 0.25) ** 2 + (0.25 - 0.5) ** 2) / 4
    if limit is not None:
        expected = (3.0 + 3.0) / 4  # each error of 2 counts 1 * (2 * 2 - 1)
    assert result.value.item() == pytest.approx(expected)


def test_the_depth_error_limit_reaches_every_masked_depth_term():
    from types import SimpleNamespace

    from simplenerf.method.objective import MaskedDepthTerm, Objective, build_terms
    from simplenerf.method.reliability import TrustAll

    objective = Objective(coarse_fine_mask=TrustAll(), depth_error_limit=0.5)
    points = SimpleNamespace(name="points", depth_weight=0.1, mask=TrustAll(), stage="coarse",
                             concentration_weight=None)
    masked = [t for t in build_terms(objective, [points], {}).values() if isinstance(t, MaskedDepthTerm)]
    assert [(t.name, t.depth_error_limit) for t in masked] == [("points", 0.5), ("cfc", 0.5)]
    with pytest.raises(ValueError, match="depth_error_limit must be a positive"):
        Objective(depth_error_limit=0.0)


def test_a_scheduled_tv_weight_is_applied_and_logged(batch, monkeypatch):
    """A grid's total variation is a term (`tv_<field>`): a `LossWeightSchedule` sets its weight, the step adds
    weight * TV to the loss and logs both the TV and its weight."""
    from types import SimpleNamespace

    from simplenerf.model.grid import KPlanesField
    from simplenerf.model.nerf import NeRF
    from simplenerf.run.callbacks import LossWeightSchedule

    torch.manual_seed(0)
    grid = {"resolutions": [8, 16], "features": 4, "hidden": 8}
    nerf = NeRF(KPlanesField(**grid, tv_weight=0.01), KPlanesField(**grid, tv_weight=0.01), num_coarse=8, num_fine=8)
    model = SimpleNeRF(nerf)
    assert {"tv_coarse", "tv_fine"} <= set(model.terms) and model.terms["tv_fine"].weight == 0.01
    schedule = LossWeightSchedule({"tv_fine": [(0, 0.5), (2, 0.25)]})
    schedule.on_train_batch_start(SimpleNamespace(global_step=2), model, batch, 0)
    assert model.terms["tv_fine"].weight == 0.25 and model.terms["tv_coarse"].weight == 0.01
    loss, logged = step(model, batch, monkeypatch)
    assert logged["train_params/tv_fine"] == 0.25 and logged["train_params/tv_coarse"] == 0.01
    assert logged["train/loss_tv_fine"] == nerf.fine.regularization("tv").detach() > 0
    expected = (logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"]
                + 0.01 * logged["train/loss_tv_coarse"] + 0.25 * logged["train/loss_tv_fine"])
    assert torch.allclose(loss, expected)


def test_a_part_whose_terms_are_all_off_is_not_backpropagated(batch, monkeypatch):
    model = SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, num_layers=2, width=16, skip_layer=1),
                       objective=Objective(sparse_depth_weight=0.0), rays_per_backward=1000)  # random, then sparse
    loss, logged = step(model, batch, monkeypatch)
    assert "train/loss_sparse_depth" not in logged and torch.allclose(loss, logged["train/loss_color"])


def test_depth_smoothness_reads_the_unseen_patches_main_depth_only(datamodule, batch, monkeypatch):
    """With `depth_smoothness_weight`, the coarse and fine terms are RegNeRF's smoothness of the expected NDC t of the
    main renders of the batch's unseen patches, rendered without colour and without the augmentations, in the step's
    loss with their weight; in a part of their own when the batch is cut into parts."""
    from dataclasses import replace

    from simplenerf.data.datasets import RandomRays
    from simplenerf.method.losses import depth_smoothness_loss, expected_ndc_t

    unseen = next(iter(RandomRays(datamodule.train_views, 64, near=1.0, unseen_patches=2, patch_size=4))).unseen
    with_patches = replace(batch, unseen=unseen)
    model = simplenerf_module(rays_per_backward=40)
    for name in ("points", "views", "cfc"):
        model.terms[name].weight = 0.0
    model.terms["coarse_depth_smoothness"].weight = model.terms["fine_depth_smoothness"].weight = 0.5
    rendered = []
    original = model.render_part
    monkeypatch.setattr(model, "render_part", lambda part: rendered.append(original(part)) or rendered[-1])
    loss, logged = step(model, with_patches, monkeypatch)
    assert [r.kind for r in rendered[-1]] == ["unseen"] and len(rendered) == 2 + 1 + 1  # 64 random, 16 sparse
    patches = rendered[-1][0]
    assert patches.renders.augmented == {} and patches.renders.main.fine.rgb is None
    for stage in ("coarse", "fine"):
        samples = getattr(patches.renders.main, f"{stage}_samples")
        depth = expected_ndc_t(patches.renders[stage].weights, samples.t)
        assert torch.allclose(logged[f"train/loss_{stage}_depth_smoothness"], depth_smoothness_loss(depth, 4).detach())
    smoothness = logged["train/loss_coarse_depth_smoothness"] + logged["train/loss_fine_depth_smoothness"]
    assert smoothness > 0
    assert torch.allclose(loss, logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"] + 0.5 * smoothness)


def test_a_depth_smoothness_weight_without_unseen_patches_is_refused():
    from simplenerf.errors import DataError
    from simplenerf.run.callbacks import LossWeightSchedule
    from simplenerf.run.checks import check_unseen_patches

    model = simplenerf_module()
    check_unseen_patches(model, [], 0)  # off: nothing to serve
    scheduled = LossWeightSchedule({"fine_depth_smoothness": [(0, 0.0), (100, 0.1)]})
    with pytest.raises(DataError, match="fine_depth_smoothness read patches from unseen cameras.*"
                                        "unseen_patches_per_batch"):
        check_unseen_patches(model, [scheduled], 0)
    check_unseen_patches(model, [scheduled], 4)
    model.terms["coarse_depth_smoothness"].weight = 0.1
    with pytest.raises(DataError, match="the loss terms coarse_depth_smoothness read"):
        check_unseen_patches(model, [], 0)


def test_distortion_and_colour_spread_terms_can_read_an_augmentations_render(datamodule, monkeypatch):
    """`DistortionTerm` and `ColorSpreadTerm` given `render`: the same losses on that augmentation's render (at the
    main samples of its stage), named after it, schedulable like any term; they train that augmentation's field and
    nothing of the main model."""
    from simplenerf.method.augmentations import Augmentation
    from simplenerf.method.losses import color_spread_loss, distortion_loss
    from simplenerf.method.objective import ColorSpreadTerm, DistortionTerm
    from simplenerf.model.fields import RadianceField

    torch.manual_seed(0)
    size = {"num_layers": 2, "width": 16, "skip_layer": 1}
    augs = [Augmentation("points", RadianceField(density_bands=3, **size), depth_weight=0.0),
            Augmentation("views", RadianceField(view_dependent=False, **size), depth_weight=0.0)]
    terms = [DistortionTerm("coarse", 0.5, render="points"), ColorSpreadTerm("coarse", 2.0, render="views")]
    model = SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, **size), augmentations=augs,
                       objective=Objective(color_weight=0.0, sparse_depth_weight=0.0, terms=terms))
    assert {"points_distortion", "views_color_spread"} <= set(model.terms)
    # its own terms: an augmentation whose depth term is off stays rendered (not retired) while these are on
    assert model.own_terms("points") == ["points", "points_distortion"]
    assert model.own_terms("views") == ["views", "views_color_spread"]
    rendered = []
    original = model.render_part
    monkeypatch.setattr(model, "render_part", lambda part: rendered.append(original(part)) or rendered[-1])
    loss, logged = run_step(model, datamodule, monkeypatch)
    part = rendered[0][0]
    assert part.kind == "random"
    t = part.renders.main.coarse_samples.t
    points, views = part.renders["points"], part.renders["views"]
    assert torch.allclose(logged["train/loss_points_distortion"], distortion_loss(points.weights, t).detach())
    assert torch.allclose(logged["train/loss_views_color_spread"],
                          color_spread_loss(views.weights, views.sample_rgb, views.rgb).detach())
    assert logged["train/loss_points_distortion"] > 0 and logged["train/loss_views_color_spread"] > 0
    assert torch.allclose(loss, 0.5 * logged["train/loss_points_distortion"]
                          + 2.0 * logged["train/loss_views_color_spread"])
    grads = {name: p.grad for name, p in model.named_parameters()}
    for index in (0, 1):  # each term trains its augmentation's field
        assert any(g is not None and g.any() for n, g in grads.items() if n.startswith(f"augmentations.{index}."))
    assert all(g is None or not g.any() for n, g in grads.items() if n.startswith("nerf."))
    with pytest.raises(ValueError, match="reads the render 'point'.*coarse, fine, points, views"):
        SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, **size), augmentations=augs,
                   objective=Objective(terms=[DistortionTerm("coarse", 0.5, render="point")]))
    augs[0].stage = "fine"  # the points augmentation at the fine samples: its distortion needs their t
    with pytest.raises(ValueError, match="needs stage 'fine'"):
        SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, **size), augmentations=augs,
                   objective=Objective(terms=[DistortionTerm("coarse", 0.5, render="points")]))


def test_a_retired_augmentations_regularisers_leave_its_field_alone(datamodule, monkeypatch):
    """A retired augmentation is not rendered, and its field's regulariser (a grid's TV) is left out of the step too:
    its planes get no gradient (before, the TV alone moved them every step after retirement). Not retired, the TV
    is in the step and trains them."""
    from simplenerf.method.augmentations import Augmentation
    from simplenerf.model.grid import KPlanesField

    size = {"num_layers": 2, "width": 16, "skip_layer": 1}
    for retired in (frozenset(), frozenset({"points"})):
        torch.manual_seed(0)
        aug = Augmentation("points", KPlanesField(resolutions=[4], features=4, hidden=8, tv_weight=0.1),
                           depth_weight=0.0)
        model = SimpleNeRF(mlp_nerf(num_coarse=8, num_fine=8, **size), augmentations=[aug],
                           objective=Objective(color_weight=0.0, sparse_depth_weight=0.0))
        assert "tv_points" in model.terms and model.terms["tv_points"].weight == 0.1
        model.retired = retired
        _, logged = run_step(model, datamodule, monkeypatch)
        planes = [p.grad for n, p in model.named_parameters() if n.startswith("augmentations.0.field.planes")]
        if retired:
            assert "train/loss_tv_points" not in logged and all(g is None for g in planes)
        else:
            assert logged["train/loss_tv_points"] > 0 and all(g is not None and g.any() for g in planes)
