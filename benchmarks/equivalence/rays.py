"""Rays of both sides compared: seeded pixels of each view, our rays and colours there, the release's from its
preprocessed ray cache (`nerf_data`: rays_o, rays_d, their NDC versions and target_rgb, flat over view x row x
column), and the rows that compare them (world and NDC origins and directions, colours).
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks.equivalence.report import Row, compare

RAY_RTOL, RAY_ATOL = 1e-5, 1e-5  # float32 rays of magnitude ~1-10: atol covers components that cross zero


def pixels(rng: np.random.Generator, views: int, height: int, width: int, per_view: int) -> np.ndarray:
    """[views * per_view, 3] (view, u, v) of distinct seeded pixels of each view."""
    out = []
    for view in range(views):
        flat = rng.choice(height * width, size=min(per_view, height * width), replace=False)
        out.append(np.stack([np.full_like(flat, view), flat % width, flat // width], -1))
    return np.concatenate(out)


def ours_rays(views, pix: np.ndarray, near: float):
    uv = torch.from_numpy(pix[:, 1:]).long()
    view = torch.from_numpy(pix[:, 0]).long()
    rays = views.rays(view, uv, near)
    return rays, views.images[view, uv[:, 1], uv[:, 0]]


def release_rays(cache: dict, pix: np.ndarray, height: int, width: int):
    flat = torch.from_numpy(pix[:, 0] * height * width + pix[:, 2] * width + pix[:, 1]).long()
    keys = ("rays_o", "rays_d", "rays_o_ndc", "rays_d_ndc", "target_rgb")
    return {k: cache[k][flat.to(cache[k].device)].cpu() for k in keys}


def ray_rows(group: str, what: str, ours, rel: dict, ours_rgb=None, note: str = "") -> list[Row]:
    """World and NDC origins and directions (and colours) of rays; `note` goes on the first row."""
    rows = [
        compare(group, f"{what}: world ray origins", ours.origins, rel["rays_o"], RAY_RTOL, RAY_ATOL, note=note),
        compare(group, f"{what}: world ray directions", ours.directions, rel["rays_d"], RAY_RTOL, RAY_ATOL),
        compare(group, f"{what}: NDC ray origins", ours.ndc_origins, rel["rays_o_ndc"], RAY_RTOL, RAY_ATOL),
        compare(group, f"{what}: NDC ray directions", ours.ndc_directions, rel["rays_d_ndc"], RAY_RTOL, RAY_ATOL),
    ]
    if ours_rgb is not None:
        rows.append(compare(group, f"{what}: pixel colours", ours_rgb, rel["target_rgb"], 0.0, 1e-7))
    return rows
