"""Volume rendering with the conventions of the authors' release (paper Sec. 3; src/models/SimpleNeRF01.py,
volume_rendering and get_z_vals_coarse / get_z_vals_fine).

Naming: t = NDC sample positions [R, S]; delta = interval lengths; sigma = density; alpha = 1 - exp(-sigma delta);
T = transmittance; w = weights = alpha T. Depth is always metric camera-z depth (see `rays.ndc_to_metric_t`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderOutputs:
    """What one field renders along a batch of rays."""

    rgb: torch.Tensor | None  # [R, 3]; None where the field skipped colour (`Samples.color` False)
    depth: torch.Tensor  # [R] metric depth, normalised by accumulation
    accumulation: torch.Tensor  # [R] sum of weights
    weights: torch.Tensor  # [R, S]
    sample_rgb: torch.Tensor | None = None  # [R, S, 3] the samples' colours that `rgb` composites (None: no colour)

    def __getitem__(self, index: slice) -> RenderOutputs:
        """The outputs of a subset of the rays."""
        rgb = None if self.rgb is None else self.rgb[index]
        sample_rgb = None if self.sample_rgb is None else self.sample_rgb[index]
        return RenderOutputs(rgb, self.depth[index], self.accumulation[index], self.weights[index], sample_rgb)


def deltas(t: torch.Tensor, ndc_directions: torch.Tensor) -> torch.Tensor:
    """Interval lengths in NDC space.

    delta_i = (t_{i+1} - t_i) |d_ndc|; the last interval runs to t = 1 (infinity in NDC), not 1e10.

    Args:
        t: [R, S] sorted, in [0, 1]. ndc_directions: [R, 3].

    Returns:
        [R, S].
    """
    dt = torch.cat([t[:, 1:] - t[:, :-1], 1.0 - t[:, -1:]], dim=-1)
    return dt * torch.linalg.vector_norm(ndc_directions, dim=-1, keepdim=True)


def density(raw: torch.Tensor, noise_std: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """sigma = ReLU(raw + noise), noise ~ N(0, noise_std^2) (training only: pass 0 at test)."""
    if noise_std > 0:
        raw = raw + noise_std * torch.randn(raw.shape, device=raw.device, dtype=raw.dtype, generator=generator)
    return torch.relu(raw)


def cut_near(sigma: torch.Tensor, ndc_z: torch.Tensor, min_ndc_z: float) -> torch.Tensor:
    """Density with every sample in front of NDC z = `min_ndc_z` emptied: a field confined to the box z >=
    min_ndc_z. Simple-TensoRF's points augmentation has its box from NDC z -0.5 (the main model's from -1), which
    "removes most of the floaters close to the camera" (Simple-RF, arXiv 2404.19015; release:
    runs/training/train1546/Configs.json, `bounding_box`; points outside a TensoRF box have density 0,
    src/models/SimpleTensoRF09.py). With LLFF's scaling (near plane = 0.75 x the nearest bound), NDC z -0.5 is
    depth 4/3 near, the nearest SfM bound.

    Args:
        sigma: [R, S] density. ndc_z: [R, S] NDC z of the samples (in [-1, 1); -1 is the near plane).

    Returns:
        [R, S]: sigma where ndc_z >= min_ndc_z, else 0 (no gradient reaches the field there).
    """
    assert sigma.shape == ndc_z.shape, f"sigma {tuple(sigma.shape)} vs ndc_z {tuple(ndc_z.shape)}"
    return torch.where(ndc_z >= min_ndc_z, sigma, torch.zeros_like(sigma))


def compute_weights(sigma: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """w_i = alpha_i prod_{j<i} (1 - alpha_j + 1e-10).

    Args:
        sigma, delta: [R, S].

    Returns:
        w [R, S].
    """
    alpha = 1.0 - torch.exp(-sigma * delta)
    transmittance = torch.cumprod(1.0 - alpha + 1e-10, dim=-1)
    transmittance = torch.cat([torch.ones_like(transmittance[:, :1]), transmittance[:, :-1]], dim=-1)
    return alpha * transmittance


def composite(w: torch.Tensor, rgb: torch.Tensor | None, t_metric: torch.Tensor) -> RenderOutputs:
    """Colour, depth and accumulation from weights.

    depth = sum(w t_metric) / (sum(w) + 1e-6): the expected termination depth among the rays that terminate.

    Args:
        w: [R, S]. rgb: [R, S, 3] (None: no colour is rendered). t_metric: [R, S].
    """
    acc = w.sum(-1)
    return RenderOutputs(
        rgb=None if rgb is None else (w[..., None] * rgb).sum(-2),
        depth=(w * t_metric).sum(-1) / (acc + 1e-6),
        accumulation=acc,
        weights=w,
        sample_rgb=rgb,
    )
