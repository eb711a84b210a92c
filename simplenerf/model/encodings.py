"""Positional encoding gamma(x, d1, d2) of the paper (Sec. 3).

gamma(x, 0, L) = [x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)]: the identity is included, there
is no pi factor, and the blocks are ordered by frequency. Because of that order, the encoding of every band range
is a contiguous slice of the full encoding, which lets the main field and its simplified augmentations share one
encoding of the same sample points (`band_slice`).
"""

from __future__ import annotations

import torch


def encoded_dim(in_dim: int, num_bands: int, include_input: bool = True) -> int:
    """Width of gamma(x, 0, num_bands) for an `in_dim`-dimensional x."""
    return in_dim * (2 * num_bands + int(include_input))


def positional_encoding(x: torch.Tensor, num_bands: int) -> torch.Tensor:
    """gamma(x, 0, num_bands).

    Args:
        x: [..., C] coordinates.
        num_bands: L, the number of frequency bands 2^0 .. 2^(L-1).

    Returns:
        [..., C * (2L + 1)]: x, then sin and cos of each band, ordered by frequency.
    """
    if num_bands == 0:
        return x
    freqs = 2.0 ** torch.arange(num_bands, device=x.device, dtype=x.dtype)  # [L]
    scaled = x[..., None, :] * freqs[:, None]  # [..., L, C]
    bands = torch.stack([torch.sin(scaled), torch.cos(scaled)], dim=-2)  # [..., L, 2, C]
    return torch.cat([x, bands.flatten(-3)], dim=-1)


def band_slice(in_dim: int, first_band: int, last_band: int, include_input: bool) -> slice:
    """The slice of gamma(x, 0, L) (L >= last_band) that holds the bands first_band .. last_band - 1.

    With `include_input` the identity block is included too, which requires `first_band == 0`:
    band_slice(3, 0, 3, True) is gamma(p, 0, 3) (21 dims); band_slice(3, 3, 10, False) is the residual high bands
    of the points augmentation (42 dims).
    """
    if include_input and first_band != 0:
        raise ValueError("the identity block precedes band 0; include_input needs first_band == 0")
    if not 0 <= first_band <= last_band:
        raise ValueError(f"invalid band range [{first_band}, {last_band})")
    start = 0 if include_input else in_dim * (1 + 2 * first_band)
    return slice(start, in_dim * (1 + 2 * last_band))
