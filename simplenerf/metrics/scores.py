"""Evaluation metrics: PSNR, SSIM and LPIPS on 8-bit images, depth MAE and depth SROCC, full-frame and masked.

Image conventions: images are channels-last float tensors in [0, 1], batched as [B, H, W, 3] (a single frame,
[H, W, 3], is what `evaluate_frame` takes). Before PSNR, SSIM and LPIPS, prediction and target are quantised the way
a saved PNG would be, round(clip(x, 0, 1) * 255), so that the reported numbers can be reproduced from stored images.

Definitions (Sec. 5.1, checked line by line against the authors' evaluation code, src/qa/*/src/*.py of the release;
docs/evaluation.md):
- PSNR: 10 log10(255^2 / MSE) per frame; with a mask the MSE runs over the masked pixels only. Identical images would
  give +inf, which is capped at `PSNR_CAP` (100 dB), full-frame and masked alike, so that means over frames stay finite
  and a perfect frame always reports exactly `PSNR_CAP`.
- SSIM map (`ssim_map`): skimage's `structural_similarity(..., gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, full=True)` on 8-bit images: per channel, local means, variances and covariance under
  a Gaussian of sigma 1.5 truncated at 3.5 sigma (11 taps, normalised), population (biased) statistics, K1 = 0.01,
  K2 = 0.03, data range 255. The map has the image's size: near the borders the window reaches outside the image,
  which is mirrored (scipy.ndimage's mode 'reflect': d c b a | a b c d | d c b a, the edge pixel repeated).
- SSIM (`ssim`): the mean of the map without its 5-pixel border (skimage's crop by (win_size - 1) // 2), i.e. over
  the window positions that lie entirely inside the image, and over channels.
- Masked SSIM (`masked_ssim`): the prediction with every pixel outside the mask replaced by the ground truth, its SSIM
  map against the ground truth, averaged over the mask's pixels (border included) and channels.
- Depth MAE: mean(|gt - pred|) / median(gt) without any scale/shift alignment; with a mask the mean runs over the
  masked pixels but the median is that of the whole frame's reference depth.
- Depth SROCC: Spearman's rank correlation over the pixels (masked: the masked pixels), ties receiving average ranks.
- Masked LPIPS: LPIPS of the prediction with every pixel outside the mask replaced by the ground truth.

The accumulation runs in float64 (float32 on MPS, which has no float64): SSIM's local variances E[x^2] - E[x]^2 on
values up to 255 cancel badly in float32, and evaluation cost is negligible next to rendering.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F

from simplenerf.metrics.lpips import LPIPS

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


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (clipped) to 8 bits, same shape: round(clip(x, 0, 1) * 255), the levels `quantize_8bit`
    scores. Every 8-bit picture of the package (PNGs, videos, the viewer, point colours, SfM's images) is made here."""
    return np.round(np.clip(image, 0.0, 1.0) * 255).astype(np.uint8)


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


def _mirror_indices(n: int, pad: int, device: torch.device) -> torch.Tensor:
    """Indices [n + 2 pad] that extend 0 .. n-1 by `pad` on both sides as scipy.ndimage's mode 'reflect'."""
    i = torch.remainder(torch.arange(-pad, n + pad, device=device), 2 * n)
    return torch.where(i >= n, 2 * n - 1 - i, i)


def _check_ssim_size(pred: torch.Tensor) -> None:
    if min(pred.shape[1], pred.shape[2]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {tuple(pred.shape[1:3])}")


def ssim_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """SSIM at every pixel of 8-bit-quantised images, mirrored at the borders (definition in the module docstring).

    Args:
        pred: [B, H, W, 3] in [0, 1], with H, W >= 11.
        target: [B, H, W, 3] in [0, 1].

    Returns:
        [B, H, W, 3] SSIM per pixel and channel, in the work dtype (float64; float32 on MPS).
    """
    _check_images(pred, target)
    _check_ssim_size(pred)
    x = quantize_8bit(pred).permute(0, 3, 1, 2)  # [B, 3, H, W]
    y = quantize_8bit(target.to(pred.device)).permute(0, 3, 1, 2)
    channels, (h, w) = x.shape[1], x.shape[2:]
    stacked = torch.cat([x, y, x * x, y * y, x * y], dim=1)  # [B, 5C, H, W]
    window = _gaussian_window(SSIM_WINDOW, SSIM_SIGMA, stacked)
    groups, pad = stacked.shape[1], SSIM_WINDOW // 2
    # The 2-D Gaussian is separable: mirror-pad one axis, one 1-D depthwise 'valid' pass, then the other axis.
    padded = stacked.index_select(3, _mirror_indices(w, pad, stacked.device))
    blurred = F.conv2d(padded, window.view(1, 1, 1, -1).expand(groups, 1, 1, SSIM_WINDOW), groups=groups)
    padded = blurred.index_select(2, _mirror_indices(h, pad, stacked.device))
    blurred = F.conv2d(padded, window.view(1, 1, -1, 1).expand(groups, 1, SSIM_WINDOW, 1), groups=groups)
    mu_x, mu_y, e_xx, e_yy, e_xy = blurred.split(channels, dim=1)
    var_x = e_xx - mu_x**2
    var_y = e_yy - mu_y**2
    cov_xy = e_xy - mu_x * mu_y
    c1 = (SSIM_K1 * _DATA_RANGE) ** 2
    c2 = (SSIM_K2 * _DATA_RANGE) ** 2
    values = ((2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return values.permute(0, 2, 3, 1)


def ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """SSIM of 8-bit-quantised images: the mean of `ssim_map` without its 5-pixel border, over pixels and channels.

    Args:
        pred: [B, H, W, 3] in [0, 1], with H, W >= 11.
        target: [B, H, W, 3] in [0, 1].

    Returns:
        [B] SSIM per frame.
    """
    pad = SSIM_WINDOW // 2
    return ssim_map(pred, target)[:, pad:-pad, pad:-pad].mean(dim=(1, 2, 3))


def masked_ssim(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, fill: bool = True) -> torch.Tensor:
    """SSIM over a mask: the mean of the SSIM map over the mask's pixels (border pixels included) and channels.

    Args:
        pred: [B, H, W, 3] in [0, 1], with H, W >= 11.
        target: [B, H, W, 3] in [0, 1].
        mask: [B, H, W] bool, True on the evaluated pixels; an empty mask gives NaN.
        fill: replace the prediction outside the mask by the target before computing the map (the authors'
            evaluation, whose numbers the paper reports); False: the map of the prediction as it is.

    Returns:
        [B] masked SSIM per frame.
    """
    mask = mask.to(pred.device)
    values = ssim_map(fill_unmasked(pred, target, mask) if fill else pred, target)  # [B, H, W, 3]
    weight = mask.to(values.dtype)[..., None]  # [B, H, W, 1]
    return (values * weight).sum(dim=(1, 2, 3)) / (weight.sum(dim=(1, 2, 3)) * values.shape[-1])


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
    # torch.median returns the lower middle element for even counts; the release's numpy.median (src/qa/06_DepthMAE/
    # src/DepthMAE02_NeRF_LLFF.py) averages the two middles.
    ordered = torch.sort(x).values
    n = ordered.numel()
    return 0.5 * (ordered[(n - 1) // 2] + ordered[n // 2])


def depth_mae(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """mean(|gt - pred|) / median(gt), no alignment; with a mask, the mean over the masked pixels and the median of
    the whole reference depth map (as the authors' evaluation normalises).

    Args:
        pred: [H, W] (or any shape) predicted depth.
        gt: ground-truth depth with as many elements as pred.
        mask: optional bool mask with as many elements; True marks the pixels the mean runs over.

    Returns:
        0-dim tensor.
    """
    p, g = _valid_depths(pred, gt, mask)
    scale = _median(gt.reshape(-1).to(device=g.device, dtype=g.dtype))
    return (g - p).abs().mean() / scale


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

    With a mask: PSNR over the masked pixels; SSIM = `masked_ssim` (the SSIM map of `fill_unmasked(pred, gt, mask)`
    against gt, averaged over the mask); LPIPS of `fill_unmasked(pred, gt, mask)` against gt; depth MAE over the
    masked pixels, normalised by the whole frame's median reference depth; SROCC over the masked pixels.

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
    if batch_mask is None:
        filled, structure = pred, ssim(pred, gt)
    else:
        filled, structure = fill_unmasked(pred, gt, batch_mask), masked_ssim(pred, gt, batch_mask)
    result = FrameMetrics(psnr=float(psnr(pred, gt, batch_mask)[0]), ssim=float(structure[0]))
    if lpips_net is not None:
        result.lpips = float(lpips(filled, gt, lpips_net)[0])
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
    "masked_ssim",
    "psnr",
    "quantize_8bit",
    "ssim",
    "ssim_map",
]
