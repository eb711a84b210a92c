"""Cameras no train view has: RegNeRF's unobserved viewpoints (Niemeyer et al., CVPR 2022, Sec. 3.2), from which
patches are rendered for a depth-smoothness prior (`method.losses.depth_smoothness_loss`).

RegNeRF samples LLFF's unseen cameras along a spiral fitted to all of the scene's poses; with two or three train views
there is no spiral to fit, so here a camera is a random point of the train centres' convex hull, moved within the
train cameras' mean image plane by up to `spread` times the mean distance between a train centre and its nearest
other one, looking along the train cameras' mean axis. Conventions are `geometry.rays`'.
"""

from __future__ import annotations

import math

import torch

from simplenerf.geometry.views import nearest_views


def mean_rotation(c2w: torch.Tensor) -> torch.Tensor:
    """The cameras' mean orientation [3, 3] (columns right, up, back; `poses.average_pose`'s rule): the mean viewing
    axis, the mean up vector made orthogonal to it.

    Args:
        c2w: [V, 3, 4].
    """
    back = torch.nn.functional.normalize(c2w[:, :, 2].sum(0), dim=0)
    right = torch.nn.functional.normalize(torch.linalg.cross(c2w[:, :, 1].sum(0), back), dim=0)
    return torch.stack([right, torch.linalg.cross(back, right), back], dim=-1)


def unseen_cameras(c2w: torch.Tensor, count: int, spread: float, generator: torch.Generator) -> torch.Tensor:
    """`count` random cameras around the train cameras `c2w` [V, 3, 4] (V >= 2): c2w [count, 3, 4].

    The centre is a uniformly random point of the simplex of train centres (flat Dirichlet weights), plus an offset
    uniform over a disc in the mean camera's right-up plane of radius `spread` x the mean nearest-neighbour distance
    of the train centres; the orientation is `mean_rotation`. Draws from `generator` only (on the CPU).
    """
    if c2w.ndim != 3 or c2w.shape[0] < 2:
        raise ValueError(f"unseen cameras need at least 2 train cameras, got c2w of shape {tuple(c2w.shape)}")
    if spread < 0:
        raise ValueError(f"spread must be >= 0, got {spread}")
    centres, rotation = c2w[:, :, 3], mean_rotation(c2w)
    scale = spread * (centres - centres[nearest_views(c2w)]).norm(dim=-1).mean()
    draws = torch.rand(count, len(c2w) + 2, generator=generator, dtype=c2w.dtype).to(c2w.device)
    weights = -torch.log(draws[:, : len(c2w)].clamp_min(1e-12))  # exponential draws, normalised: flat Dirichlet
    weights = weights / weights.sum(-1, keepdim=True)
    radius, angle = scale * draws[:, -2].sqrt(), 2 * math.pi * draws[:, -1]  # uniform over the disc
    offset = radius[:, None] * (angle.cos()[:, None] * rotation[:, 0] + angle.sin()[:, None] * rotation[:, 1])
    position = weights @ centres + offset
    return torch.cat([rotation.expand(count, 3, 3), position[:, :, None]], dim=-1)
