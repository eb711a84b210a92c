"""Tests of simplenerf.metrics.scores against hand-computed values, a slow SSIM reference and scipy."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
import scipy.ndimage
import scipy.stats
import torch

from simplenerf.metrics.lpips import LPIPS, WEIGHTS_ENV
from simplenerf.metrics.scores import (
    MASKED_METRIC_NAMES,
    METRIC_NAMES,
    PSNR_CAP,
    FrameMetrics,
    depth_mae,
    depth_srocc,
    evaluate_frame,
    fill_unmasked,
    frame_scores,
    masked_ssim,
    psnr,
    quantize_8bit,
    ssim,
    ssim_map,
)
from tests.conftest import require_shared


def lpips_weights() -> Path:
    """The real LPIPS weights: $SIMPLENERF_LPIPS_WEIGHTS if it names a file, else ../shared's npz (skip if absent)."""
    env = os.environ.get(WEIGHTS_ENV)
    if env and Path(env).is_file():
        return Path(env)
    return require_shared("data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz")


def _levels(values: np.ndarray) -> torch.Tensor:
    """8-bit levels as a float32 image in [0, 1]."""
    return torch.from_numpy(values.astype(np.float32) / 255.0)


def _ssim_reference(pred: np.ndarray, target: np.ndarray) -> float:
    """Direct SSIM of 8-bit images [H, W, 3]: explicit loop over every valid 11x11 window of every channel."""
    offsets = np.arange(11) - 5.0
    g = np.exp(-(offsets**2) / (2 * 1.5**2))
    w = np.outer(g, g)
    w /= w.sum()
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    x_all = np.round(np.clip(pred, 0, 1) * 255).astype(np.float64)
    y_all = np.round(np.clip(target, 0, 1) * 255).astype(np.float64)
    values = []
    for c in range(3):
        for i in range(x_all.shape[0] - 10):
            for j in range(x_all.shape[1] - 10):
                x = x_all[i : i + 11, j : j + 11, c]
                y = y_all[i : i + 11, j : j + 11, c]
                mx, my = (w * x).sum(), (w * y).sum()
                vx, vy = (w * (x - mx) ** 2).sum(), (w * (y - my) ** 2).sum()
                cxy = (w * (x - mx) * (y - my)).sum()
                values.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
    return float(np.mean(values))


def test_quantize_rounds_and_clips() -> None:
    x = torch.tensor([-0.2, 0.0, 0.5, 10.4 / 255, 1.0, 1.7])
    assert quantize_8bit(x).tolist() == [0.0, 0.0, 128.0, 10.0, 255.0, 255.0]


def test_psnr_constant_error() -> None:
    rng = np.random.default_rng(0)
    levels = rng.integers(20, 230, size=(2, 6, 7, 3))
    target = _levels(levels)
    pred = _levels(levels + np.array([10, 5]).reshape(2, 1, 1, 1))
    expected = [20 * math.log10(255 / 10), 20 * math.log10(255 / 5)]
    torch.testing.assert_close(psnr(pred, target), torch.tensor(expected, dtype=torch.float64))


def test_psnr_ignores_sub_quantum_differences_and_caps() -> None:
    target = torch.rand(1, 5, 5, 3)
    assert psnr(target, target).item() == PSNR_CAP
    nudged = _levels(np.round(target.numpy() * 255)) + 0.2 / 255
    assert psnr(nudged, target).item() == PSNR_CAP
    # Values beyond [0, 1] are clipped before comparison.
    assert psnr(torch.full((1, 4, 4, 3), 1.5), torch.ones(1, 4, 4, 3)).item() == PSNR_CAP


def test_psnr_mask() -> None:
    target = torch.full((1, 3, 3, 3), 100 / 255)
    pred = target.clone()
    mask = torch.zeros(1, 3, 3, dtype=torch.bool)
    mask[0, :2, :2] = True
    pred[0, 2, 2] = 0.0  # outside the mask: ignored
    assert psnr(pred, target, mask).item() == PSNR_CAP
    pred[0, 0, 0] = 130 / 255  # 1 of 4 masked pixels off by 30 in every channel: MSE = 900 / 4
    assert psnr(pred, target, mask).item() == pytest.approx(20 * math.log10(255 / 15), abs=1e-9)


def test_ssim_identical_is_one() -> None:
    x = torch.rand(2, 16, 13, 3)
    torch.testing.assert_close(ssim(x, x), torch.ones(2, dtype=torch.float64))


def test_ssim_constant_images_closed_form() -> None:
    # Zero variance everywhere, so SSIM reduces to the luminance term (2ab + C1) / (a^2 + b^2 + C1).
    a, b = 100.0, 110.0
    c1 = (0.01 * 255) ** 2
    got = ssim(torch.full((1, 12, 12, 3), a / 255), torch.full((1, 12, 12, 3), b / 255)).item()
    assert got == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), abs=1e-12)


def test_ssim_matches_slow_reference() -> None:
    rng = np.random.default_rng(1)
    target = rng.random((2, 16, 19, 3))
    # Correlated but distorted prediction, partly out of range, so all SSIM terms matter.
    pred = 0.7 * target + 0.3 * rng.random((2, 16, 19, 3)) + rng.normal(0, 0.05, (2, 16, 19, 3))
    got = ssim(torch.from_numpy(pred).float(), torch.from_numpy(target).float())
    for k in range(2):
        p32, t32 = pred[k].astype(np.float32), target[k].astype(np.float32)
        assert got[k].item() == pytest.approx(_ssim_reference(p32, t32), abs=1e-5)


def test_ssim_rejects_small_images() -> None:
    with pytest.raises(ValueError):
        ssim(torch.rand(1, 10, 20, 3), torch.rand(1, 10, 20, 3))


def _ssim_map_reference(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """skimage's full SSIM map of 8-bit images [H, W, 3], written with scipy: per channel, gaussian_filter with sigma
    1.5, truncate 3.5 and mode 'reflect' for the local statistics, population covariance, data range 255."""
    x_all = np.round(np.clip(pred, 0, 1) * 255).astype(np.float64)
    y_all = np.round(np.clip(target, 0, 1) * 255).astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    channels = []
    for c in range(3):
        x, y = x_all[..., c], y_all[..., c]

        def blur(a: np.ndarray) -> np.ndarray:
            return scipy.ndimage.gaussian_filter(a, sigma=1.5, truncate=3.5, mode="reflect")

        mx, my = blur(x), blur(y)
        vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
        channels.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
    return np.stack(channels, axis=-1)


def _random_pair(seed: int, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random target, a noisy prediction (8-bit levels / 255, float64) and a random mask of [h, w]."""
    rng = np.random.default_rng(seed)
    target = rng.integers(0, 256, size=(h, w, 3)) / 255.0
    pred = np.clip(target + rng.normal(0.0, 0.15, size=(h, w, 3)), 0.0, 1.0)
    return pred, target, rng.random((h, w)) > 0.4


@pytest.mark.parametrize("size", [(11, 11), (19, 30), (33, 14)])
def test_ssim_map_matches_scipy_reference_including_borders(size) -> None:
    pred, target, _ = _random_pair(7, *size)
    got = ssim_map(torch.from_numpy(pred)[None], torch.from_numpy(target)[None])[0].numpy()
    assert got.shape == (*size, 3)
    np.testing.assert_allclose(got, _ssim_map_reference(pred, target), rtol=0.0, atol=1e-12)
    # The scalar SSIM is the mean of the map without its 5-pixel border (skimage's crop).
    full = ssim(torch.from_numpy(pred)[None], torch.from_numpy(target)[None]).item()
    assert full == pytest.approx(_ssim_map_reference(pred, target)[5:-5, 5:-5].mean(), abs=1e-12)


def test_masked_ssim_is_the_map_of_the_filled_prediction_averaged_over_the_mask() -> None:
    pred, target, mask = _random_pair(8, 24, 29)
    filled = np.where(mask[..., None], pred, target)
    expected = _ssim_map_reference(filled, target)[mask].mean()
    t = [torch.from_numpy(a)[None] for a in (pred, target, mask)]
    assert masked_ssim(*t).item() == pytest.approx(expected, abs=1e-12)
    unfilled = _ssim_map_reference(pred, target)[mask].mean()
    assert masked_ssim(*t, fill=False).item() == pytest.approx(unfilled, abs=1e-12)
    assert masked_ssim(*t).item() > unfilled  # windows across the mask's edge see the ground truth outside
    # A full mask averages the whole map, border included, so it differs from the cropped scalar SSIM.
    everywhere = torch.ones(1, 24, 29, dtype=torch.bool)
    assert masked_ssim(t[0], t[1], everywhere).item() == pytest.approx(_ssim_map_reference(pred, target).mean())
    assert math.isnan(masked_ssim(t[0], t[1], torch.zeros(1, 24, 29, dtype=torch.bool)).item())


def test_ssim_map_border_mirrors_the_edge_pixel() -> None:
    # Columns 0..10 of a ramp image: mirroring repeats column 0 (scipy 'reflect'), so the map of an image and of its
    # left-right flip are each other's flips, and a constant image has a map of exactly 1 at its borders too.
    pred, target, _ = _random_pair(9, 12, 15)
    a = ssim_map(torch.from_numpy(pred)[None], torch.from_numpy(target)[None])[0]
    b = ssim_map(torch.from_numpy(pred[:, ::-1].copy())[None], torch.from_numpy(target[:, ::-1].copy())[None])[0]
    torch.testing.assert_close(b, a.flip(1), rtol=0.0, atol=1e-12)
    flat = torch.full((1, 12, 12, 3), 0.5, dtype=torch.float64)
    assert torch.equal(ssim_map(flat, flat), torch.ones(1, 12, 12, 3, dtype=torch.float64))


def test_fill_unmasked() -> None:
    pred = torch.arange(12.0).reshape(2, 2, 3)
    target = -torch.ones(2, 2, 3)
    mask = torch.tensor([[True, False], [False, True]])
    expected = torch.tensor([[[0.0, 1, 2], [-1, -1, -1]], [[-1, -1, -1], [9, 10, 11]]])
    assert torch.equal(fill_unmasked(pred, target, mask), expected)


def test_depth_mae_hand_values() -> None:
    gt = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    pred = torch.tensor([[1.0, 2.0], [3.0, 6.0]])
    assert depth_mae(pred, gt).item() == pytest.approx(0.5 / 2.5)  # even count: median averages 2 and 3
    mask = torch.tensor([[True, True], [False, True]])
    # Masked: the mean over the 3 masked pixels, (0 + 0 + 2) / 3, over the WHOLE frame's median 2.5 (not the
    # masked pixels' median 2).
    assert depth_mae(pred, gt, mask).item() == pytest.approx((2 / 3) / 2.5)


def test_depth_srocc_hand_values() -> None:
    gt = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    assert depth_srocc(gt**3 + 5, gt).item() == pytest.approx(1.0)
    assert depth_srocc(-gt, gt).item() == pytest.approx(-1.0)
    # Ranks with ties: pred [1, 1, 2, 3] -> [1.5, 1.5, 3, 4]; gt ranks [1, 2, 3, 4]. Pearson of ranks = 4.5/sqrt(4.5*5).
    pred = torch.tensor([[1.0, 1.0], [2.0, 3.0]])
    assert depth_srocc(pred, gt).item() == pytest.approx(4.5 / math.sqrt(4.5 * 5.0), abs=1e-12)


def test_depth_metrics_match_scipy_with_ties_and_mask() -> None:
    rng = np.random.default_rng(2)
    gt = rng.integers(1, 8, size=(9, 11)).astype(np.float64)
    pred = gt + rng.integers(-2, 3, size=(9, 11))
    mask = rng.random((9, 11)) > 0.3
    got = depth_srocc(torch.from_numpy(pred), torch.from_numpy(gt), torch.from_numpy(mask)).item()
    assert got == pytest.approx(scipy.stats.spearmanr(pred[mask], gt[mask]).statistic, abs=1e-12)
    mae = depth_mae(torch.from_numpy(pred), torch.from_numpy(gt), torch.from_numpy(mask)).item()
    assert mae == pytest.approx(np.mean(np.abs(gt[mask] - pred[mask])) / np.median(gt), abs=1e-12)


def test_evaluate_frame() -> None:
    torch.manual_seed(3)
    gt = torch.rand(32, 32, 3)
    pred = gt.clone()
    pred[24:, 24:] = 1.0 - pred[24:, 24:]  # only outside the mask
    mask = torch.zeros(32, 32, dtype=torch.bool)
    mask[:24] = True
    depth = torch.rand(32, 32) + 1.0
    net = LPIPS()  # random weights: identical inputs still give exactly 0

    masked = evaluate_frame(pred, gt, 2 * depth, depth, net, mask)
    assert isinstance(masked, FrameMetrics)
    assert masked.psnr == PSNR_CAP
    assert masked.ssim == pytest.approx(1.0, abs=1e-12)
    assert masked.lpips == 0.0
    assert masked.depth_mae == pytest.approx(depth[mask].mean().item() / np.median(depth.numpy()), rel=1e-6)
    assert masked.depth_srocc == pytest.approx(1.0)

    full = evaluate_frame(pred, gt)
    assert full.psnr < PSNR_CAP and full.ssim < 1.0
    assert full.lpips is None and full.depth_mae is None and full.depth_srocc is None
    assert set(full.as_dict()) == {"psnr", "ssim", "lpips", "depth_mae", "depth_srocc"}


def assert_perfect_scores(scores: Mapping[str, float | None]) -> None:
    """The documented scores of a prediction equal to the ground truth, full-frame and masked (also used by the
    evaluator's tests)."""
    for prefix in ("", "masked_"):
        assert scores[f"{prefix}psnr"] == PSNR_CAP
        assert scores[f"{prefix}ssim"] == pytest.approx(1.0, abs=1e-12)
        assert scores[f"{prefix}lpips"] == 0.0
        assert scores[f"{prefix}depth_mae"] == 0.0
        assert scores[f"{prefix}depth_srocc"] == pytest.approx(1.0, abs=1e-12)


def test_frame_scores_of_a_perfect_prediction() -> None:
    """Prediction = ground truth, with the real LPIPS network: the documented perfect scores, full and masked."""
    net = LPIPS.from_weights(lpips_weights())
    torch.manual_seed(4)
    gt = torch.rand(40, 48, 3)
    depth = torch.rand(40, 48) + 1.0
    mask = torch.rand(40, 48) > 0.3
    scores = frame_scores(gt.clone(), gt, depth.clone(), depth, net, mask)
    assert list(scores) == [*METRIC_NAMES, *MASKED_METRIC_NAMES]
    assert_perfect_scores(scores)


def test_frame_scores_masked_equal_evaluate_frame_and_null_when_not_computable() -> None:
    torch.manual_seed(5)
    gt = torch.rand(24, 24, 3)
    pred = (gt + 0.1 * torch.randn(24, 24, 3)).clamp(0, 1)
    depth = torch.rand(24, 24) + 1.0
    mask = torch.zeros(24, 24, dtype=torch.bool)
    mask[4:20, 2:18] = True
    scores = frame_scores(pred, gt, 1.1 * depth, depth, None, mask)
    full = evaluate_frame(pred, gt, 1.1 * depth, depth)
    masked = evaluate_frame(pred, gt, 1.1 * depth, depth, None, mask)
    assert {k: scores[k] for k in METRIC_NAMES} == full.as_dict()
    assert {k: scores[f"masked_{k}"] for k in METRIC_NAMES} == masked.as_dict()
    assert scores["lpips"] is None and scores["masked_lpips"] is None
    assert scores["masked_psnr"] != scores["psnr"]

    no_mask = frame_scores(pred, gt, depth, depth)
    empty = frame_scores(pred, gt, depth, depth, None, torch.zeros(24, 24, dtype=torch.bool))
    for scores in (no_mask, empty):
        assert all(scores[k] is None for k in MASKED_METRIC_NAMES)
    # SROCC of a constant depth map is undefined (NaN): reported as None, not NaN.
    constant = frame_scores(pred, gt, torch.ones(24, 24), depth, None, mask)
    assert constant["depth_srocc"] is None and constant["masked_depth_srocc"] is None
    assert constant["depth_mae"] is not None
