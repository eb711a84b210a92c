"""The parts of the release-equivalence check that do not need the release: its table's pass rules, the replay of
random draws into our sampling code, and the skip layer's column permutation."""

from __future__ import annotations

import math
import re
import sys

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


def test_device_option_names_what_this_machine_cannot_give(monkeypatch, capsys):
    from benchmarks.equivalence import check

    assert check.check_device("cpu") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for spec, message in [("cuda", "no CUDA device (torch.cuda.is_available() is False"),
                          ("meta", "runs on cpu or cuda[:N], not meta"), ("gpu0", "not a device name")]:
        with pytest.raises(check.DeviceError, match=re.escape(message)):
            check.check_device(spec)
    # through the command: one line, exit status 2, before the release is looked for
    assert check.main(["--release-src", "/nonexistent/src", "--device", "cuda"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("release_equivalence: --device 'cuda': no CUDA device") and err.count("\n") == 1
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert check.check_device("cuda") == torch.device("cuda", 0)
    assert check.check_device("cuda:1") == torch.device("cuda", 1)
    with pytest.raises(check.DeviceError, match=re.escape("has 2 CUDA device(s)")):
        check.check_device("cuda:2")


def test_release_device_replaces_the_releases_device_choice_while_it_builds(monkeypatch):
    """The release's classes ask `utils.CommonUtils01.get_device(config["device"])` in their constructors (cuda:0
    whenever CUDA is available); within `release_device` they get the check's device, after it their own rule."""
    import types

    from benchmarks.equivalence.release import release_device

    def get_device(configured):
        return torch.device(f"cuda:{configured[0]}")

    common = types.ModuleType("utils.CommonUtils01")
    common.get_device = get_device
    utils = types.ModuleType("utils")
    utils.CommonUtils01 = common
    monkeypatch.setitem(sys.modules, "utils", utils)
    monkeypatch.setitem(sys.modules, "utils.CommonUtils01", common)
    with release_device(torch.device("cpu")):
        assert common.get_device([0]) == torch.device("cpu")
    assert common.get_device is get_device
    with pytest.raises(KeyError), release_device(torch.device("cpu")):
        raise KeyError("restored on an error too")
    assert common.get_device([1]) == torch.device("cuda:1")


def test_trajectory_floor_perturbation_moves_each_weight_by_one_ulp():
    """The ulp-perturbed twin (drawing its signs on the CPU and moving them to each weight's device, so that a module
    on a GPU works too) moves every weight of 1.0 to 1 +- 2^-23, both signs drawn, and leaves the module alone."""
    from benchmarks.equivalence.trajectory import FLOAT32_ULP, ulp_perturbed

    module = torch.nn.Linear(8, 8)
    torch.nn.init.ones_(module.weight), torch.nn.init.ones_(module.bias)
    twin = ulp_perturbed(module)
    moved = torch.cat([(q - 1).flatten() for q in twin.parameters()])
    assert torch.equal(moved.abs(), torch.full_like(moved, FLOAT32_ULP))
    assert (moved > 0).any() and (moved < 0).any()
    assert torch.equal(module.weight, torch.ones(8, 8))
