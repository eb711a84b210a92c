"""Loss terms of the paper's total loss (Sec. 4.4). Each is a mean over rays of a batch."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from simplenerf.model.rendering import RenderOutputs


def color_loss(renders: Sequence[RenderOutputs], target: torch.Tensor) -> torch.Tensor:
    """L_color = sum over the given renders of ||c - c_hat||^2 (mean over rays and channels).

    Args:
        renders: outputs of the main coarse and fine fields (and of each augmentation).
        target: [R, 3] ground-truth colours.
    """
    return sum(torch.mean((r.rgb - target) ** 2) for r in renders)


def sparse_depth_loss(renders: Sequence[RenderOutputs], depth: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """L_sd = sum over the given renders of weight * ||z - z_hat||^2 (mean over rays), z_hat the SfM depth.

    Args:
        renders: outputs at the sparse-depth rays of the main fine field and of each augmentation (not main coarse).
        depth: [R] SfM depths. weight: [R] per-point weights (ones unless DS-NeRF's weighting is on).
    """
    return sum(torch.mean(weight * (r.depth - depth) ** 2) for r in renders)


def coarse_fine_sparse_loss(coarse: RenderOutputs, fine: RenderOutputs) -> torch.Tensor:
    """The release's addition to L_cfc on the sparse-depth rays: mean (z_coarse - sg(z_fine))^2, unmasked."""
    return torch.mean((coarse.depth - fine.depth.detach()) ** 2)


@torch.no_grad()
def psnr_of_mse(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """PSNR of float colours in [0, 1], -10 log10(MSE): a training / validation progress signal, not the 8-bit
    evaluation metric (`simplenerf.metrics.scores.psnr`)."""
    return -10.0 * torch.log10(torch.mean((rgb - target.to(rgb)) ** 2))


def bin_sizes(num_samples: int, num_bins: int) -> list[int]:
    """Sizes of `num_bins` consecutive groups of `num_samples` samples: num_samples // num_bins each, one more for
    the num_samples % num_bins bins at evenly spaced indices (linspace(0, num_bins - 1, remainder), truncated), as
    the release groups them (Simple-RF, src/loss_functions/MassConcentrationLoss06.py). 32 in 5: [7, 6, 6, 6, 7]."""
    if not 0 < num_bins <= num_samples:
        raise ValueError(f"need 1 to {num_samples} bins for {num_samples} samples, got {num_bins}")
    base, remainder = divmod(num_samples, num_bins)
    bigger = set(torch.linspace(0, num_bins - 1, remainder).long().tolist()) if remainder else set()
    return [base + (i in bigger) for i in range(num_bins)]


def mass_concentration_loss(weights: torch.Tensor, num_bins: int = 5, eps: float = 1e-3) -> torch.Tensor:
    """Simple-RF's mass-concentration loss on an augmentation's rays (arXiv 2404.19015; release:
    src/loss_functions/MassConcentrationLoss06.py, weight 0.01 from step 5k of 25k in
    runs/training/train1546/Configs.json): the ray weights summed in `num_bins` consecutive groups of samples
    (`bin_sizes`), then the entropy sum_b -(W_b + eps) log(W_b + eps), mean over rays. Low when the mass is in
    one bin (an opaque surface); high when spread along the ray (a translucent fog whose depth could win a reliability
    mask wrongly). Not normalised by the accumulation, as the release.

    Args:
        weights: [R, S] rendering weights along R rays (the augmentation's, at the main model's coarse samples).

    Returns:
        a scalar.
    """
    assert weights.dim() == 2, f"weights must be [R, S], got {tuple(weights.shape)}"
    binned = torch.stack([w.sum(-1) for w in torch.split(weights, bin_sizes(weights.shape[1], num_bins), dim=-1)],
                         dim=-1)  # [R, num_bins]
    return torch.special.entr(binned + eps).sum(-1).mean()


def color_spread_loss(weights: torch.Tensor, sample_rgb: torch.Tensor, rgb: torch.Tensor) -> torch.Tensor:
    """The weighted variance of the samples' colours about the ray's rendered colour, sum_i w_i |c_i - C|^2 with
    C = sum_i w_i c_i, mean over rays: 0 when every sample that carries weight has the pixel's colour, as on an
    opaque surface. Not in the paper. A render whose colour is a blend of different colours along the ray matches
    its training view and no other: from a camera moved sideways the blend falls apart into a smear
    (docs/results.md "Where the blur and the streaks come from", 13).

    Args:
        weights: [R, S]. sample_rgb: [R, S, 3]. rgb: [R, 3] the composite.
    """
    return (weights * (sample_rgb - rgb[:, None, :]).pow(2).sum(-1)).sum(-1).mean()


def distortion_loss(weights: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Mip-NeRF 360's distortion loss (Barron et al., CVPR 2022, eq. 15), on sorted samples: low when each ray's
    weight sits in one short interval (a surface), high when it is spread along the ray (a fog, whose mean depth
    can still match every depth loss). Here the intervals are [t_i, t_i+1) of the samples' NDC t (in [0, 1), the
    normalised ray distance of a forward-facing scene), the last one as long as the one before it:

        L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 d_i,   m_i, d_i: the intervals' midpoints and lengths,

    the double sum in O(S) through prefix sums (2 sum_i w_i (m_i W_<i - (w m)_<i)). Mean over rays.

    Args:
        weights: [R, S] rendering weights. t: [R, S] the samples' NDC t, ascending along each ray.

    Returns:
        a scalar.
    """
    assert weights.shape == t.shape and weights.dim() == 2, f"need [R, S] weights and t, got {weights.shape}, {t.shape}"
    lengths = torch.diff(t, dim=-1)
    lengths = torch.cat([lengths, lengths[:, -1:]], dim=-1)  # [R, S]
    mids = t + 0.5 * lengths
    before_w = torch.cumsum(weights, dim=-1) - weights  # W_<i
    before_wm = torch.cumsum(weights * mids, dim=-1) - weights * mids
    inter = 2.0 * (weights * (mids * before_w - before_wm)).sum(-1)
    intra = (weights**2 * lengths).sum(-1) / 3.0
    return (inter + intra).mean()


def expected_ndc_t(weights: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Each ray's expected NDC t, sum_i w_i t_i + (1 - sum_i w_i) * 1: the weight a ray leaves is at t = 1 (infinity
    in NDC), so the value is in [0, 1] whatever the accumulation. [R, S] weights and t -> [R]."""
    return (weights * t).sum(-1) + (1.0 - weights.sum(-1))


def depth_smoothness_loss(depth: torch.Tensor, size: int) -> torch.Tensor:
    """RegNeRF's depth smoothness (Niemeyer et al., CVPR 2022, eq. 2) on square patches of rays from unseen cameras:
    the squared differences of neighbouring pixels' depths, down the rows and along the columns, here a mean over
    every such pair of neighbours (RegNeRF sums them) instead of a sum. Not in the paper.

    Args:
        depth: [P * size * size] the patches' depths, each patch row-major (`data.batches.UnseenPatches`).
        size: the patches' side.

    Returns:
        a scalar.
    """
    patches = depth.reshape(-1, size, size)
    down, along = torch.diff(patches, dim=1), torch.diff(patches, dim=2)
    return (down.square().sum() + along.square().sum()) / (down.numel() + along.numel())
