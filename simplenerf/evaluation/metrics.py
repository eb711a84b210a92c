"""Evaluation metrics: PSNR, SSIM and LPIPS on 8-bit images, depth MAE and depth SROCC.

Image conventions: images are channels-last float tensors in [0, 1], batched as [B, H, W, 3] (a single frame,
[H, W, 3], is what `evaluate_frame` takes). Before PSNR, SSIM and LPIPS, prediction and target are quantised the way
a saved PNG would be, round(clip(x, 0, 1) * 255), so that the reported numbers can be reproduced from stored images.

Definitions (from the project SPEC):
- PSNR: 10 log10(255^2 / MSE) per frame; with a mask the MSE runs over the masked pixels only. Identical images would
  give +inf, which is capped at `PSNR_CAP` (100 dB), full-frame and masked alike, so that means over frames stay finite
  and a perfect frame always reports exactly `PSNR_CAP`.
- SSIM: 11x11 Gaussian window with sigma 1.5, K1 = 0.01, K2 = 0.03, data range 255, population (biased) local
  variances and covariance, averaged over the 'valid' window positions (no padding) and over channels.
  torchmetrics' SSIM is not used: it reflect-pads the images and averages over the padded full-size map, which
  differs from the 'valid' definition.
- Depth MAE: mean(|gt - pred|) / median(gt) over the valid pixels, without any scale/shift alignment.
- Depth SROCC: Spearman's rank correlation over the valid pixels, ties receiving average ranks (as scipy).
- Masked scores (SPEC 7, `frame_scores`): PSNR and the depth metrics over the mask's pixels; SSIM and LPIPS of the
  prediction with every pixel outside the mask replaced by the ground truth.

The accumulation runs in float64 (float32 on MPS, which has no float64): SSIM's local variances E[x^2] - E[x]^2 on
values up to 255 cancel badly in float32, and evaluation cost is negligible next to rendering.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

from simplenerf.evaluation.lpips import LPIPS

PSNR_CAP = 100.0
"""PSNR (dB) reported for a frame (or masked region) whose quantised prediction equals the quantised target."""

METRIC_NAMES = ("psnr", "ssim", "lpips", "depth_mae", "depth_srocc")
"""Full-frame metrics, in the order of outputs and tables."""

MASKED_METRIC_NAMES = tuple(f"masked_{name}" for name in METRIC_NAMES)
"""The same metrics over a frame's visibility mask (`frame_scores`)."""

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
_DATA_RANGE = 255.0


def _work_dtype(x: torch.Tensor) -> torch.dtype:
    return torch.float32 if x.device.type == "mps" else torch.float64


def quantize_8bit(x: torch.Tensor) -> torch.Tensor:
    """round(clip(x, 0, 1) * 255), as a float tensor of integer values in [0, 255]."""
    return torch.round(x.to(_work_dtype(x)).clamp(0.0, 1.0) * _DATA_RANGE)


def _check_images(pred: torch.Tensor, target: torch.Tensor) -> None:
    if pred.ndim != 4 or pred.shape[-1] != 3 or pred.shape != target.shape:
        raise ValueError(f"expected pred and target of equal shape [B, H, W, 3], got {pred.shape} and {target.shape}")


def psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR (dB) of 8-bit-quantised images, capped at `PSNR_CAP`.

    Args:
        pred: [B, H, W, 3] in [0, 1].
        target: [B, H, W, 3] in [0, 1].
        mask: optional [B, H, W] bool; the MSE then runs over masked pixels only (an empty mask gives NaN).

    Returns:
        [B] PSNR per frame.
    """
    _check_images(pred, target)
    sq_err = (quantize_8bit(pred) - quantize_8bit(target.to(pred.device))) ** 2  # [B, H, W, 3]
    if mask is None:
        mse = sq_err.mean(dim=(1, 2, 3))
    else:
        weight = mask.to(device=sq_err.device, dtype=sq_err.dtype)[..., None]  # [B, H, W, 1]
        mse = (sq_err * weight).sum(dim=(1, 2, 3)) / (weight.sum(dim=(1, 2, 3)) * sq_err.shape[-1])
    value = 10.0 * torch.log10(_DATA_RANGE**2 / mse)  # mse == 0 gives +inf, capped below
    return torch.clamp(value, max=PSNR_CAP)


def _gaussian_window(size: int, sigma: float, like: torch.Tensor) -> torch.Tensor:
    offsets = torch.arange(size, device=like.device, dtype=like.dtype) - (size - 1) / 2
    window = torch.exp(-(offsets**2) / (2.0 * sigma**2))
    return window / window.sum()


def ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """SSIM of 8-bit-quantised images (definition in the module docstring).

    Args:
        pred: [B, H, W, 3] in [0, 1], with H, W >= 11.
        target: [B, H, W, 3] in [0, 1].

    Returns:
        [B] SSIM per frame, averaged over valid window positions and channels.
    """
    _check_images(pred, target)
    if min(pred.shape[1], pred.shape[2]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {tuple(pred.shape[1:3])}")
    x = quantize_8bit(pred).permute(0, 3, 1, 2)  # [B, 3, H, W]
    y = quantize_8bit(target.to(pred.device)).permute(0, 3, 1, 2)
    channels = x.shape[1]
    stacked = torch.cat([x, y, x * x, y * y, x * y], dim=1)  # [B, 5C, H, W]
    window = _gaussian_window(SSIM_WINDOW, SSIM_SIGMA, stacked)
    groups = stacked.shape[1]
    # The 2-D Gaussian is separable: two 1-D depthwise passes without padding give the 'valid' weighted means.
    blurred = F.conv2d(stacked, window.view(1, 1, 1, -1).expand(groups, 1, 1, SSIM_WINDOW), groups=groups)
    blurred = F.conv2d(blurred, window.view(1, 1, -1, 1).expand(groups, 1, SSIM_WINDOW, 1), groups=groups)
    mu_x, mu_y, e_xx, e_yy, e_xy = blurred.split(channels, dim=1)
    var_x = e_xx - mu_x**2
    var_y = e_yy - mu_y**2
    cov_xy = e_xy - mu_x * mu_y
    c1 = (SSIM_K1 * _DATA_RANGE) ** 2
    c2 = (SSIM_K2 * _DATA_RANGE) ** 2
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return ssim_map.mean(dim=(1, 2, 3))


def lpips(pred: torch.Tensor, target: torch.Tensor, net: LPIPS) -> torch.Tensor:
    """LPIPS of 8-bit-quantised images.

    Args:
        pred: [B, H, W, 3] in [0, 1].
        target: [B, H, W, 3] in [0, 1].
        net: the LPIPS network; inputs are moved to its device and dtype.

    Returns:
        [B] LPIPS per frame.
    """
    _check_images(pred, target)
    x = (quantize_8bit(pred) / _DATA_RANGE).permute(0, 3, 1, 2)
    y = (quantize_8bit(target.to(pred.device)) / _DATA_RANGE).permute(0, 3, 1, 2)
    with torch.no_grad():
        return net(x, y)


def fill_unmasked(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """`pred` with every pixel outside `mask` replaced by `target`, so that only masked pixels can differ.

    Args:
        pred: [..., H, W, C] image(s).
        target: same shape as pred.
        mask: [..., H, W] bool, True where pred is kept.
    """
    return torch.where(mask.to(pred.device)[..., None], pred, target.to(device=pred.device, dtype=pred.dtype))


def _valid_depths(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    if pred.numel() != gt.numel():
        raise ValueError(f"depth maps differ in size: {pred.shape} vs {gt.shape}")
    dtype = _work_dtype(pred)
    p = pred.reshape(-1).to(dtype)
    g = gt.reshape(-1).to(device=pred.device, dtype=dtype)
    if mask is not None:
        keep = mask.reshape(-1).to(device=pred.device, dtype=torch.bool)
        p, g = p[keep], g[keep]
    return p, g


def _median(x: torch.Tensor) -> torch.Tensor:
    # torch.median returns the lower middle element for even counts; the SPEC's median averages the two middles.
    ordered = torch.sort(x).values
    n = ordered.numel()
    return 0.5 * (ordered[(n - 1) // 2] + ordered[n // 2])


def depth_mae(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """mean(|gt - pred|) / median(gt) over valid pixels (all, or those in `mask`); no alignment.

    Args:
        pred: [H, W] (or any shape) predicted depth.
        gt: ground-truth depth with as many elements as pred.
        mask: optional bool mask with as many elements; True marks valid pixels.

    Returns:
        0-dim tensor.
    """
    p, g = _valid_depths(pred, gt, mask)
    return (g - p).abs().mean() / _median(g)


def _average_ranks(x: torch.Tensor) -> torch.Tensor:
    """1-based ranks, tied values sharing the mean of their ranks (scipy.stats.rankdata 'average')."""
    _, inverse, counts = torch.unique(x, sorted=True, return_inverse=True, return_counts=True)
    ends = torch.cumsum(counts, dim=0).to(x.dtype)  # last 1-based rank of each distinct value
    group_rank = ends - (counts.to(x.dtype) - 1.0) / 2.0
    return group_rank[inverse]


def depth_srocc(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Spearman rank correlation between predicted and ground-truth depth over valid pixels.

    Args:
        pred, gt, mask: as in `depth_mae`.

    Returns:
        0-dim tensor in [-1, 1]; NaN when either map is constant over the valid pixels.
    """
    p, g = _valid_depths(pred, gt, mask)
    rp = _average_ranks(p)
    rg = _average_ranks(g)
    rp = rp - rp.mean()
    rg = rg - rg.mean()
    return (rp * rg).sum() / torch.sqrt((rp * rp).sum() * (rg * rg).sum())


@dataclass
class FrameMetrics:
    """Metrics of one frame; the optional ones are None when their inputs were not provided."""

    psnr: float
    ssim: float
    lpips: float | None = None
    depth_mae: float | None = None
    depth_srocc: float | None = None

    def as_dict(self) -> dict[str, float | None]:
        return asdict(self)


def evaluate_frame(
    pred_rgb: torch.Tensor,
    gt_rgb: torch.Tensor,
    pred_depth: torch.Tensor | None = None,
    gt_depth: torch.Tensor | None = None,
    lpips_net: LPIPS | None = None,
    mask: torch.Tensor | None = None,
) -> FrameMetrics:
    """All metrics of one frame.

    With a mask, PSNR averages over masked pixels, SSIM and LPIPS compare `fill_unmasked(pred, gt, mask)` with gt
    (unmasked pixels then agree exactly), and the depth metrics use masked pixels only.

    Args:
        pred_rgb: [H, W, 3] in [0, 1], any float dtype and device.
        gt_rgb: [H, W, 3] in [0, 1].
        pred_depth: optional [H, W]; depth metrics need both depths.
        gt_depth: optional [H, W].
        lpips_net: LPIPS network, or None to skip LPIPS.
        mask: optional [H, W] bool, True on evaluated pixels.
    """
    pred = pred_rgb[None]
    gt = gt_rgb[None].to(pred.device)
    batch_mask = None if mask is None else mask[None].to(pred.device)
    image_for_structure = pred if batch_mask is None else fill_unmasked(pred, gt, batch_mask)
    result = FrameMetrics(
        psnr=float(psnr(pred, gt, batch_mask)[0]),
        ssim=float(ssim(image_for_structure, gt)[0]),
    )
    if lpips_net is not None:
        result.lpips = float(lpips(image_for_structure, gt, lpips_net)[0])
    if pred_depth is not None and gt_depth is not None:
        result.depth_mae = float(depth_mae(pred_depth, gt_depth, mask))
        result.depth_srocc = float(depth_srocc(pred_depth, gt_depth, mask))
    return result


def _finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def frame_scores(
    pred_rgb: torch.Tensor,
    gt_rgb: torch.Tensor,
    pred_depth: torch.Tensor | None = None,
    gt_depth: torch.Tensor | None = None,
    lpips_net: LPIPS | None = None,
    mask: torch.Tensor | None = None,
) -> dict[str, float | None]:
    """Full-frame and masked metrics of one frame, keyed by `METRIC_NAMES` + `MASKED_METRIC_NAMES`.

    A score that cannot be computed is None: the masked ones without a mask or with an empty mask, LPIPS without a
    network, the depth ones without both depths, and any NaN (e.g. SROCC of a constant depth map).

    Args:
        pred_rgb, gt_rgb, pred_depth, gt_depth, lpips_net: as in `evaluate_frame`.
        mask: optional [H, W] bool visibility mask, True on evaluated pixels.
    """
    full = evaluate_frame(pred_rgb, gt_rgb, pred_depth, gt_depth, lpips_net).as_dict()
    scores = {name: _finite_or_none(full[name]) for name in METRIC_NAMES}
    masked: dict[str, float | None] = dict.fromkeys(METRIC_NAMES)
    if mask is not None and bool(mask.any()):
        masked = evaluate_frame(pred_rgb, gt_rgb, pred_depth, gt_depth, lpips_net, mask).as_dict()
    scores.update({f"masked_{name}": _finite_or_none(masked[name]) for name in METRIC_NAMES})
    return scores


__all__ = [
    "MASKED_METRIC_NAMES",
    "METRIC_NAMES",
    "PSNR_CAP",
    "FrameMetrics",
    "depth_mae",
    "depth_srocc",
    "evaluate_frame",
    "fill_unmasked",
    "frame_scores",
    "lpips",
    "psnr",
    "quantize_8bit",
    "ssim",
]
