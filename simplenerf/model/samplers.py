"""Sample placement along rays: stratified (coarse) and hierarchical importance sampling (fine).

Naming: `t` are sample positions in NDC, in [0, 1]; `w` are rendering weights. Shapes: R rays, S samples.
"""

from __future__ import annotations

import torch


def stratified_samples(
    num_rays: int, num_samples: int, perturb: bool, like: torch.Tensor, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Coarse samples uniform in t in [0, 1].

    Without `perturb` these are linspace(0, 1, S); with it, each sample is drawn uniformly in the interval between
    the midpoints around it (the first and last intervals are half-open at 0 and 1).

    Args:
        like: a tensor whose device and dtype the samples take.

    Returns:
        t [R, S], sorted.
    """
    t = torch.linspace(0.0, 1.0, num_samples, device=like.device, dtype=like.dtype).expand(num_rays, num_samples)
    if not perturb:
        return t.contiguous()
    mids = 0.5 * (t[:, 1:] + t[:, :-1])
    upper = torch.cat([mids, t[:, -1:]], dim=-1)
    lower = torch.cat([t[:, :1], mids], dim=-1)
    u = torch.rand(t.shape, device=t.device, dtype=t.dtype, generator=generator)
    return lower + (upper - lower) * u


def sample_pdf(
    bins: torch.Tensor,
    weights: torch.Tensor,
    num_samples: int,
    deterministic: bool,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Inverse-transform sampling of the piecewise-constant pdf given by `weights` over `bins`.

    Args:
        bins: [R, B + 1] bin edges, sorted.
        weights: [R, B] non-negative, not all zero per ray.
        deterministic: evenly spaced quantiles (test time) instead of uniform random ones.

    Returns:
        [R, num_samples] positions inside [bins[:, 0], bins[:, -1]].
    """
    assert bins.shape[-1] == weights.shape[-1] + 1, f"bins {tuple(bins.shape)} vs weights {tuple(weights.shape)}"
    pdf = weights / weights.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1)], dim=-1)  # [R, B + 1]
    if deterministic:
        u = torch.linspace(0.0, 1.0, num_samples, device=bins.device, dtype=bins.dtype).expand(bins.shape[0], -1)
    else:
        u = torch.rand(bins.shape[0], num_samples, device=bins.device, dtype=bins.dtype, generator=generator)
    u = u.contiguous()
    above = torch.searchsorted(cdf.contiguous(), u, right=True).clamp(max=cdf.shape[-1] - 1)
    below = (above - 1).clamp(min=0)
    cdf_lo, cdf_hi = cdf.gather(-1, below), cdf.gather(-1, above)
    bin_lo, bin_hi = bins.gather(-1, below), bins.gather(-1, above)
    denom = cdf_hi - cdf_lo
    denom = torch.where(denom < 1e-5, torch.ones_like(denom), denom)
    return bin_lo + (u - cdf_lo) / denom * (bin_hi - bin_lo)


def hierarchical_samples(
    t_coarse: torch.Tensor,
    w_coarse: torch.Tensor,
    num_fine: int,
    deterministic: bool,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Fine samples of the release: `num_fine` draws from the coarse weights, merged with the coarse samples.

    The pdf is w[1:-1] + 1e-5 over the midpoints of the coarse samples; it is detached, so the fine samples never
    send gradient to the coarse field.

    Args:
        t_coarse: [R, S] sorted coarse samples. w_coarse: [R, S] their weights.

    Returns:
        [R, S + num_fine] sorted.
    """
    mids = 0.5 * (t_coarse[:, 1:] + t_coarse[:, :-1])
    t_new = sample_pdf(mids, w_coarse[:, 1:-1].detach() + 1e-5, num_fine, deterministic, generator).detach()
    return torch.sort(torch.cat([t_coarse, t_new], dim=-1), dim=-1).values
