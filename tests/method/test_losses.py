"""Simple-RF's mass-concentration loss (its bins, its value on hand-computed rays, its place in the module) and
Mip-NeRF 360's distortion loss."""

import math

import pytest
import torch

from simplenerf.data.batches import RayBatch
from simplenerf.geometry.rays import make_rays
from simplenerf.method.augmentations import Augmentation
from simplenerf.method.losses import bin_sizes, color_spread_loss, distortion_loss, mass_concentration_loss
from simplenerf.method.module import SimpleNeRF
from simplenerf.method.objective import Objective, RenderedRays, part_loss
from simplenerf.method.reliability import PatchReprojectionMask
from simplenerf.model.grid import KPlanesField
from simplenerf.model.nerf import NeRF
from simplenerf.run.callbacks import LossWeightSchedule


def entr(x: float) -> float:
    return -x * math.log(x)


def test_bins_are_consecutive_groups_with_the_remainder_spread_as_the_release():
    assert bin_sizes(32, 5) == [7, 6, 6, 6, 7]  # remainder 2 at linspace(0, 4, 2) = 0, 4
    assert bin_sizes(64, 5) == [13, 13, 13, 12, 13]  # remainder 4 at 0, 1.33, 2.67, 4 -> 0, 1, 2, 4
    assert bin_sizes(7, 3) == [3, 2, 2] and bin_sizes(10, 5) == [2, 2, 2, 2, 2]
    with pytest.raises(ValueError, match="bins"):
        bin_sizes(4, 5)


def test_entropy_of_the_binned_weights_on_hand_computed_rays():
    weights = torch.tensor([[0.1, 0.2, 0.1, 0.3, 0.1, 0.0, 0.0],  # bins of 3, 2, 2 samples: 0.4, 0.4, 0
                            [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])  # all the mass in the last bin: 0, 0, 1
    spread = 2 * entr(0.401) + entr(0.001)  # eps 1e-3 added to every bin
    opaque = 2 * entr(0.001) + entr(1.001)
    assert spread == pytest.approx(0.73977, abs=1e-5) and opaque == pytest.approx(0.012815, abs=1e-6)
    loss = mass_concentration_loss(weights, num_bins=3)
    assert loss.item() == pytest.approx((spread + opaque) / 2, rel=1e-5)
    # Within one bin the distribution does not matter; across bins it does.
    assert mass_concentration_loss(weights[1:].roll(1, -1), 3).item() == pytest.approx(opaque, rel=1e-5)
    w = weights[:1].clone().requires_grad_(True)
    mass_concentration_loss(w, 3).backward()  # d/dW -(W + eps) log(W + eps) = -(log(W + eps) + 1)
    bins = [-(math.log(0.401) + 1)] * 5 + [-(math.log(0.001) + 1)] * 2
    torch.testing.assert_close(w.grad[0], torch.tensor(bins))


def small_grid(**kwargs) -> KPlanesField:
    return KPlanesField(resolutions=[4], features=2, hidden=8, **kwargs)


def grid_module(concentration_weight: float) -> SimpleNeRF:
    torch.manual_seed(0)
    augs = [Augmentation("points", small_grid(density_features=1, residual_scales_to_color=True),
                         PatchReprojectionMask(), min_ndc_z=-0.5, concentration_weight=concentration_weight),
            Augmentation("views", small_grid(view_dependent=False), PatchReprojectionMask())]
    nerf = NeRF(small_grid(), small_grid(), num_coarse=10, num_fine=6, density_noise_std=0.0)
    return SimpleNeRF(nerf, augmentations=augs, objective=Objective(coarse_fine_mask=PatchReprojectionMask()))


def ray_batch(n: int = 12) -> RayBatch:
    k = torch.tensor([[[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]]])
    c2w = torch.cat([torch.eye(3), torch.zeros(3, 1)], dim=1)[None]
    uv = torch.stack([torch.arange(n) % 32, torch.arange(n) // 32], dim=-1)
    return RayBatch(make_rays(k, c2w, uv, 32, 24, near=1.0), torch.rand(n, 3), torch.zeros(n, dtype=torch.long), uv)


def test_module_adds_the_concentration_term_of_an_augmentation_by_name():
    model = grid_module(concentration_weight=0.01)
    assert model.terms["points_concentration"].weight == 0.01 and "views_concentration" not in model.terms
    assert model.terms["points_concentration"].reads == ("random",)
    LossWeightSchedule({"points_concentration": [[0, 0.0], [5, 0.01]]}).check_model(model)  # a schedulable name
    for name in ("points", "views", "cfc"):  # no masked terms: they need the train views
        model.terms[name].weight = 0.0
    for term in model.terms.values():  # no regularisers either: only the ray terms are compared
        if term.name.startswith("tv_"):
            term.weight = 0.0
    batch = ray_batch()
    renders = model.render(batch.rays, randomized=False)
    points = renders.augmented["points"]
    cut = model.augmentations[0].min_ndc_z
    z = renders.main.coarse_samples.positions[..., 2]
    assert bool((z < cut).any()) and bool((points.weights[z < cut] == 0).all())  # empty in front of the cut
    behind = (z >= cut)[:, :-1]  # the last sample, at t = 1, has an empty interval
    assert bool((points.weights[:, :-1][behind] > 0).all())
    rendered = [RenderedRays("random", batch, renders, share=1.0)]
    part = part_loss(model.terms, rendered, regularize=False)
    assert set(part.values) == {"color", "points_concentration"}
    torch.testing.assert_close(part.values["points_concentration"], mass_concentration_loss(points.weights, 5))
    torch.testing.assert_close(part.loss, part.values["color"] + 0.01 * part.values["points_concentration"])
    model.terms["points_concentration"].weight = 0.0  # before its schedule starts: not computed
    assert set(part_loss(model.terms, rendered, regularize=False).values) == {"color"}



def test_the_objective_can_put_the_concentration_on_the_main_fine_render():
    torch.manual_seed(0)
    nerf = NeRF(small_grid(), small_grid(), num_coarse=10, num_fine=6, density_noise_std=0.0)
    model = SimpleNeRF(nerf, objective=Objective(fine_concentration_weight=0.02, concentration_bins=4))
    assert model.terms["fine_concentration"].weight == 0.02
    for term in model.terms.values():  # only colour and the concentration are compared
        if term.name.startswith("tv_"):
            term.weight = 0.0
    batch = ray_batch()
    renders = model.render(batch.rays, randomized=False)
    part = part_loss(model.terms, [RenderedRays("random", batch, renders, share=1.0)], regularize=False)
    assert set(part.values) == {"color", "fine_concentration"}
    torch.testing.assert_close(part.values["fine_concentration"], mass_concentration_loss(renders.main.fine.weights, 4))
    torch.testing.assert_close(part.loss, part.values["color"] + 0.02 * part.values["fine_concentration"])
    assert "fine_concentration" not in part_loss(  # the paper's default: off, not computed
        SimpleNeRF(NeRF(small_grid(), small_grid(), num_coarse=10, num_fine=6)).terms,
        [RenderedRays("random", batch, renders, share=1.0)], regularize=False).values


def test_distortion_is_small_for_a_surface_and_a_third_for_a_fog():
    t = torch.linspace(0, 1, 65)[:-1].expand(3, 64).contiguous()  # intervals of 1/64
    surface, fog, two = torch.zeros(64), torch.full((64,), 1 / 64), torch.zeros(64)
    surface[10] = 1.0
    two[10] = two[50] = 0.5
    loss = [distortion_loss(w[None], t[:1]).item() for w in (surface, fog, two)]
    assert loss[0] == pytest.approx(1 / 64 / 3, rel=1e-5)  # one interval: 1/3 w^2 d
    assert loss[1] == pytest.approx(1 / 3, rel=1e-5)  # uniform over [0, 1): E|m_i - m_j| = 1/3 as d -> 0
    # two halves 40 intervals apart: 2 * 0.25 * 40/64 between them + 1/3 * 2 * 0.25 / 64 within
    assert loss[2] == pytest.approx(0.5 * 40 / 64 + 0.5 / 64 / 3, rel=1e-5)


def test_distortion_matches_the_double_sum_on_uneven_samples():
    torch.manual_seed(0)
    t = torch.sort(torch.rand(4, 9), dim=-1).values
    w = torch.rand(4, 9) / 9
    d = torch.diff(t, dim=-1)
    d = torch.cat([d, d[:, -1:]], dim=-1)
    m = t + d / 2
    brute = ((w[:, :, None] * w[:, None, :] * (m[:, :, None] - m[:, None, :]).abs()).sum((1, 2))
             + (w**2 * d).sum(-1) / 3).mean()
    torch.testing.assert_close(distortion_loss(w, t), brute)


def main_render_terms(objective: Objective):
    """A small grid SimpleNeRF with `objective` (its planes' TV off), its deterministic renders of `ray_batch()` and
    the objective on them as random rays: (model, renders, part loss)."""
    torch.manual_seed(0)
    nerf = NeRF(small_grid(), small_grid(), num_coarse=10, num_fine=6, density_noise_std=0.0)
    model = SimpleNeRF(nerf, objective=objective)
    for term in model.terms.values():
        if term.name.startswith("tv_"):
            term.weight = 0.0
    batch = ray_batch()
    renders = model.render(batch.rays, randomized=False)
    part = part_loss(model.terms, [RenderedRays("random", batch, renders, share=1.0)], regularize=False)
    return model, renders, part


def test_the_objective_puts_the_distortion_on_both_main_renders():
    model, renders, part = main_render_terms(Objective(distortion_weight=0.03))
    assert model.terms["coarse_distortion"].weight == model.terms["fine_distortion"].weight == 0.03
    assert set(part.values) == {"color", "coarse_distortion", "fine_distortion"}
    main = renders.main
    torch.testing.assert_close(part.values["fine_distortion"], distortion_loss(main.fine.weights, main.fine_samples.t))
    torch.testing.assert_close(part.values["coarse_distortion"],
                               distortion_loss(main.coarse.weights, main.coarse_samples.t))
    torch.testing.assert_close(part.loss, part.values["color"] + 0.03 * (part.values["coarse_distortion"]
                                                                         + part.values["fine_distortion"]))


def test_color_spread_is_zero_for_one_colour_along_the_ray_and_the_variance_of_a_blend():
    w = torch.tensor([[0.0, 0.5, 0.5, 0.0], [0.0, 1.0, 0.0, 0.0]])
    c = torch.zeros(2, 4, 3)
    c[0, 1], c[0, 2] = 1.0, 0.0  # ray 0: half white, half black -> grey, each sample 0.5 off in every channel
    c[1] = 0.3  # ray 1: one colour
    rgb = (w[..., None] * c).sum(-2)
    assert color_spread_loss(w[1:], c[1:], rgb[1:]).item() == 0.0
    assert color_spread_loss(w[:1], c[:1], rgb[:1]).item() == pytest.approx(3 * 0.25)  # 0.5 * 3 * 0.25 * 2
    assert color_spread_loss(w, c, rgb).item() == pytest.approx(3 * 0.25 / 2)  # mean over rays


def test_the_objective_puts_the_color_spread_on_both_main_renders():
    _, renders, part = main_render_terms(Objective(color_spread_weight=0.1))
    assert set(part.values) == {"color", "coarse_color_spread", "fine_color_spread"}
    fine = renders.main.fine
    assert fine.sample_rgb.shape == (*fine.weights.shape, 3)
    torch.testing.assert_close(fine.rgb, (fine.weights[..., None] * fine.sample_rgb).sum(-2))
    torch.testing.assert_close(part.values["fine_color_spread"],
                               color_spread_loss(fine.weights, fine.sample_rgb, fine.rgb))
    torch.testing.assert_close(part.loss, part.values["color"] + 0.1 * (part.values["coarse_color_spread"]
                                                                        + part.values["fine_color_spread"]))


def test_expected_ndc_t_puts_the_weight_a_ray_leaves_at_infinity():
    from simplenerf.method.losses import expected_ndc_t

    weights, t = torch.tensor([[0.5, 0.25], [0.0, 0.0]]), torch.tensor([[0.2, 0.6], [0.2, 0.6]])
    assert torch.allclose(expected_ndc_t(weights, t), torch.tensor([0.5 * 0.2 + 0.25 * 0.6 + 0.25, 1.0]))


def test_depth_smoothness_is_the_mean_squared_neighbour_difference_of_each_patch():
    from simplenerf.method.losses import depth_smoothness_loss

    flat, bands, steps = [[0.5, 0.5], [0.5, 0.5]], [[0.0, 0.0], [1.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]
    assert depth_smoothness_loss(torch.tensor(flat).flatten(), 2).item() == 0.0
    # Two 2 x 2 patches, each with 4 neighbour pairs: bands differ down both columns, steps along both rows.
    assert depth_smoothness_loss(torch.tensor([bands, steps]).flatten(), 2).item() == pytest.approx(4 / 8)
    # 3 x 3 with one pixel raised by 2: its 4 neighbour pairs differ by 2, out of 12 pairs.
    patch = torch.zeros(3, 3)
    patch[1, 1] = 2.0
    assert depth_smoothness_loss(patch.flatten(), 3).item() == pytest.approx(4 * 4 / 12)
