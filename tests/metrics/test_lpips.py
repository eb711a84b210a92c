"""Tests of metrics.lpips: published LPIPS v0.1 values, weight lookup order and the missing-weights error."""

from __future__ import annotations

import urllib.error
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from simplenerf.metrics import lpips as lpips_module
from simplenerf.metrics.lpips import ALEXNET_FILENAME, LPIPS, WEIGHTS_ENV, LPIPSWeightsNotFound
from tests.conftest import require_shared

# Values printed by the reference implementation's test script for net='alex', version 0.1.
PUBLISHED = {"ex_p0": 0.7219, "ex_p1": 0.1376}


def _npz_path() -> Path:
    return require_shared("data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz")


def _read_example(name: str) -> torch.Tensor:
    """[1, 3, H, W] RGB in [0, 1]."""
    path = require_shared(f"data/lpips/examples/{name}.png")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255.0


def _example_distances(net: LPIPS) -> torch.Tensor:
    ref = _read_example("ex_ref")
    others = torch.cat([_read_example("ex_p0"), _read_example("ex_p1")])
    return net(torch.cat([ref, ref]), others)


def _write_torchvision_pth(npz: Path, dest: Path) -> Path:
    """A torchvision-layout AlexNet state dict built from the npz trunk, with classifier keys that must be ignored."""
    with np.load(npz) as archive:
        state = {k: torch.from_numpy(archive[k].copy()) for k in archive.files if k.startswith("features.")}
    state["classifier.1.weight"] = torch.zeros(4, 9216)
    state["classifier.1.bias"] = torch.zeros(4)
    dest.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, dest)
    return dest


@pytest.fixture(scope="module")
def npz_net() -> LPIPS:
    return LPIPS.from_weights(_npz_path())


@pytest.fixture
def clean_lookup(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """No env var and an empty torch hub dir; returns the hub dir."""
    hub = tmp_path / "hub"
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))
    return hub


def test_published_values(npz_net: LPIPS) -> None:
    dist = _example_distances(npz_net)
    assert dist.shape == (2,)
    assert dist[0].item() == pytest.approx(PUBLISHED["ex_p0"], abs=1e-4)
    assert dist[1].item() == pytest.approx(PUBLISHED["ex_p1"], abs=1e-4)


def test_identical_images_give_zero() -> None:
    torch.manual_seed(0)
    net = LPIPS()  # random weights suffice: identical features cancel exactly
    x = torch.rand(2, 3, 40, 48)
    assert torch.equal(net(x, x), torch.zeros(2))


def test_too_small_images_rejected() -> None:
    with pytest.raises(ValueError, match="at least 31x31"):
        LPIPS()(torch.rand(1, 3, 30, 64), torch.rand(1, 3, 30, 64))
    LPIPS()(torch.rand(1, 3, 31, 31), torch.rand(1, 3, 31, 31))


def test_frozen_and_eval(npz_net: LPIPS) -> None:
    assert not npz_net.training
    assert all(not p.requires_grad for p in npz_net.parameters())


def test_float64_inputs_follow_network_dtype(npz_net: LPIPS) -> None:
    ref = _read_example("ex_ref")
    p0 = _read_example("ex_p0")
    out = npz_net(ref.double(), p0.double())
    assert out.dtype == next(npz_net.parameters()).dtype
    assert out.item() == pytest.approx(PUBLISHED["ex_p0"], abs=1e-4)


def test_torchvision_pth_matches_npz(npz_net: LPIPS, tmp_path: Path) -> None:
    pth = _write_torchvision_pth(_npz_path(), tmp_path / "alexnet.pth")
    net = LPIPS.from_weights(str(pth))
    torch.testing.assert_close(_example_distances(net), _example_distances(npz_net), rtol=0, atol=1e-6)


def test_env_var_and_hub_cache_are_used(
    npz_net: LPIPS, clean_lookup: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    expected = _example_distances(npz_net)
    _write_torchvision_pth(_npz_path(), clean_lookup / "checkpoints" / ALEXNET_FILENAME)
    torch.testing.assert_close(_example_distances(LPIPS.from_weights()), expected, rtol=0, atol=1e-6)
    monkeypatch.setenv(WEIGHTS_ENV, str(_npz_path()))
    torch.testing.assert_close(_example_distances(LPIPS.from_weights()), expected, rtol=0, atol=1e-6)


def test_heads_fall_back_to_npz(npz_net: LPIPS, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(lpips_module, "_lpips_package_heads_file", lambda: None)
    net = LPIPS.from_weights(_npz_path())
    torch.testing.assert_close(_example_distances(net), _example_distances(npz_net), rtol=0, atol=1e-6)


def test_missing_heads_raise(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(lpips_module, "_lpips_package_heads_file", lambda: None)
    state = {f"features.{i}.{n}": p for i, m in enumerate(LPIPS().features) for n, p in m.named_parameters()}
    torch.save(state, tmp_path / "trunk_only.pth")
    with pytest.raises(LPIPSWeightsNotFound, match="linear heads"):
        LPIPS.from_weights(tmp_path / "trunk_only.pth")


def _assert_helpful(message: str, hub: Path) -> None:
    assert "--evaluation.lpips_weights PATH" in message
    assert WEIGHTS_ENV in message
    assert str(hub / "checkpoints" / ALEXNET_FILENAME) in message
    assert "disable LPIPS" in message
    assert "\n" not in message


def test_missing_explicit_path_raises(clean_lookup: Path, tmp_path: Path) -> None:
    missing = tmp_path / "nope.pth"
    with pytest.raises(LPIPSWeightsNotFound) as info:
        LPIPS.from_weights(str(missing))
    assert str(missing) in str(info.value)
    _assert_helpful(str(info.value), clean_lookup)


def test_nothing_available_raises(clean_lookup: Path) -> None:
    with pytest.raises(LPIPSWeightsNotFound) as info:
        LPIPS.from_weights()
    _assert_helpful(str(info.value), clean_lookup)
    assert isinstance(info.value, RuntimeError)


def test_failed_download_raises(clean_lookup: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def offline(*args: object, **kwargs: object) -> None:
        raise urllib.error.URLError("offline")

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", offline)
    with pytest.raises(LPIPSWeightsNotFound, match="Downloading"):
        LPIPS.from_weights(allow_download=True)
