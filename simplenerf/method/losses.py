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
