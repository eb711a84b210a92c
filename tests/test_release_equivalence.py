"""The parts of the release-equivalence check that do not need the release: its table's pass rules, the replay of
random draws into our sampling code, and the skip layer's column permutation."""

from __future__ import annotations

import math

import pytest
import torch

from benchmarks.equivalence import randomness
from benchmarks.equivalence.report import Report, compare, exact
from benchmarks.equivalence.weights import release_to_ours


def test_compare_rules():
    assert compare("g", "q", [1.0, 2.0], [1.0, 2.0 + 1e-6], rtol=1e-5, atol=0).passed
    row = compare("g", "q", [1.0, 2.0], [1.0, 2.1], rtol=1e-5, atol=0)
    assert not row.passed and row.max_abs == pytest.approx(0.1) and row.max_rel == pytest.approx(0.1 / 2.1)
    assert not compare("g", "q", [1.0], [1.0, 2.0]).passed  # shapes differ
    assert not compare("g", "q", [math.nan], [1.0]).passed
    assert not exact("g", "q", [1, 0, -1], [1, 0, 1]).passed and exact("g", "q", [1, 0], [1, 0]).passed
    # norm-wise: one element off by 1e-3 of a tensor of norm 10 passes at 1e-3, not at 1e-5
    a, b = torch.full((100,), 1.0), torch.full((100,), 1.0)
    a[0] += 1e-2
    assert compare("g", "q", a, b, rtol=1e-3, relative_to="norm").passed
    assert not compare("g", "q", a, b, rtol=1e-5, relative_to="norm").passed
    report = Report()
    report.add(exact("g", "a", [1], [1]), exact("g", "b", [1], [2]))
    assert not report.passed and "1 of 2 rows pass, 1 FAIL" in report.markdown()


def test_release_draws_replay_into_our_sampling_in_our_order():
    from simplenerf.model.rendering import density
    from simplenerf.model.samplers import hierarchical_samples, stratified_samples

    rays, coarse, fine = 3, 4, 5
    g = torch.Generator().manual_seed(0)
    draws = randomness.Draws(coarse_t=torch.rand(rays, coarse, generator=g), pdf_u=torch.rand(rays, fine, generator=g),
                             noise={k: torch.randn(rays, n, generator=g) for k, n in
                                    [("coarse", coarse), ("fine", coarse + fine), ("points", coarse)]})
    like = torch.zeros(1)
    with randomness.replaying([draws], ["points"]):
        t = stratified_samples(rays, coarse, True, like)
        sigma = density(torch.zeros(rays, coarse), 1.0)
        t_fine = hierarchical_samples(t, torch.ones(rays, coarse), fine, deterministic=False)
        density(torch.zeros(rays, coarse + fine), 1.0)
        density(torch.zeros(rays, coarse), 1.0)
    lower = torch.linspace(0, 1, coarse)
    mids = 0.5 * (lower[1:] + lower[:-1])
    low, high = torch.cat([lower[:1], mids]), torch.cat([mids, lower[-1:]])
    assert torch.allclose(t, low + (high - low) * draws.coarse_t)  # the release's offsets, exactly placed
    assert torch.equal(sigma, torch.relu(draws.noise["coarse"]))
    assert t_fine.shape == (rays, coarse + fine)
    with pytest.raises(AssertionError, match="met the release's"):  # a draw of another shape is an error
        with randomness.replaying([draws], ["points"]):
            stratified_samples(rays, coarse + 1, True, like)
    with pytest.raises(AssertionError, match="not used"):  # so is a draw left over
        with randomness.replaying([draws], ["points"]):
            stratified_samples(rays, coarse, True, like)


def test_skip_layer_columns_move_from_input_first_to_input_last():
    width, encoded = 4, 3
    release = torch.arange(width * (encoded + width), dtype=torch.float32).reshape(width, encoded + width)
    ours = release_to_ours("coarse_model.pts_linears.5.weight", release)
    assert torch.equal(ours[:, :width], release[:, encoded:]) and torch.equal(ours[:, width:], release[:, :encoded])
    assert release_to_ours("coarse_model.pts_linears.4.weight", release) is release
