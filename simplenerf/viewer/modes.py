"""What the viewer renders from its camera: one `RenderMode` per choice of the "render" menu, one picture each.

- rgb: the main fine colour; depth: its depth; accumulation: its opacity (grey).
- coarse | fine depth: the main coarse depth on the left half and the fine depth on the right, with the same colours;
  where they disagree, L_cfc (paper Sec. 4.3) pulls one to the other.
- depth of an augmentation (paper Sec. 4.1, e.g. "points", "views"), evaluated at the main coarse samples.
- mask of a depth pair (an augmentation, or "cfc"): the ternary reliability mask (paper eqs. 3-7) of the train view
  nearest the camera, computed there by `SimpleNeRF.reliability_maps` and carried to the viewer's pixels by their
  main fine depth (projected into that view; no occlusion test). Green: +1, the augmented (or fine) depth is more
  reliable and supervises the main one; magenta: -1, the main depth supervises it; grey: 0, neither; dimmed colour:
  pixels that view does not see.

Depths are coloured by `viz.pictures.colorize_depth` over one fixed range (the scene's near/far bounds), so a colour is
the same depth in every render and every mode. Only the module's public parts are used: `nerf.render_rays_chunked`
(with an augmentation for its depth) and `reliability_maps`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from simplenerf.geometry.rays import RayBundle
from simplenerf.geometry.views import Views
from simplenerf.method.module import SimpleNeRF
from simplenerf.model.nerf import FrameRender
from simplenerf.viz.pictures import colorize_depth, grey_picture, to_uint8

ModeKind = Literal["rgb", "depth", "accumulation", "coarse_fine", "augmented_depth", "mask"]
MASK_COLOURS = {1: (0.1, 0.85, 0.2), -1: (0.9, 0.1, 0.8), 0: (0.5, 0.5, 0.5)}  # +1 green, -1 magenta, 0 grey


class RenderCancelled(Exception):
    """A newer request arrived while rendering: the render is abandoned between two chunks."""


@dataclass(frozen=True)
class RenderMode:
    """One entry of the render menu: a kind, and for augmented depths and masks the depth pair's name."""

    kind: ModeKind
    name: str | None = None

    @property
    def label(self) -> str:
        fixed = {"rgb": "RGB", "depth": "depth", "accumulation": "accumulation", "coarse_fine": "coarse | fine depth"}
        if self.kind in fixed:
            return fixed[self.kind]
        return f"depth: {self.name} (augmented)" if self.kind == "augmented_depth" else f"mask: {self.name}"


@dataclass
class Picture:
    """A render: the 8-bit picture [H, W, 3] shown in the browser and the main fine depth [H, W] (scene units, 0 where
    no ray was rendered) with which the browser hides the cameras and points behind the rendered surface."""

    rgb: np.ndarray
    depth: np.ndarray


def render_modes(model: SimpleNeRF) -> list[RenderMode]:
    """Every mode a model offers: the fixed ones, each augmentation's depth, and each depth pair's mask (its
    augmentations' and, with a coarse-fine mask, "cfc"; none without masks)."""
    modes = [RenderMode("rgb"), RenderMode("depth"), RenderMode("accumulation"), RenderMode("coarse_fine")]
    modes += [RenderMode("augmented_depth", aug.name) for aug in model.augmentations]
    mask_names = [aug.name for aug in model.augmentations if aug.mask is not None]
    if model.coarse_fine_mask is not None:
        mask_names.append("cfc")
    return modes + [RenderMode("mask", name) for name in mask_names]


def depth_picture(depth: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
    """8-bit RGB [H, W, 3] of depth [H, W] coloured over (closest, farthest): near warm, far cool (turbo)."""
    closest, farthest = depth_range
    return colorize_depth(depth, lo=1.0 / farthest, hi=1.0 / closest)


def mask_overlay(rgb: np.ndarray, mask_values: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The mask legend over a render: rgb [H, W, 3] in [0, 1], mask_values [H, W] in {-1, 0, 1}, seen [H, W] bool
    (pixels the mask's view sees). Seen pixels: 0.4 rgb + 0.6 the value's colour; others: 0.3 rgb. Returns 8-bit."""
    colours = np.zeros_like(rgb)
    for value, colour in MASK_COLOURS.items():
        colours[mask_values == value] = colour
    out = np.where(seen[..., None], 0.4 * rgb + 0.6 * colours, 0.3 * rgb)
    return to_uint8(out)


def sample_mask(mask: torch.Tensor, views: Views, view: int, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mask values at world points: mask [h, w] of train view `view` of `views`, points [R, 3].

    Returns:
        values [R] (the mask at the nearest pixel; 0 where unseen), seen [R] bool (in front of the view and inside
        its image).
    """
    index = torch.full((len(points),), view, device=points.device)
    uv, z = views.project(points, index)
    pixel = uv.round().long()
    inside = (pixel[:, 0] >= 0) & (pixel[:, 0] < views.width) & (pixel[:, 1] >= 0) & (pixel[:, 1] < views.height)
    seen = (z > 0) & inside
    u, v = pixel[:, 0].clamp(0, views.width - 1), pixel[:, 1].clamp(0, views.height - 1)
    values = torch.where(seen, mask.to(points.device)[v, u], torch.zeros((), dtype=mask.dtype, device=points.device))
    return values, seen


def render_rays(model, rays: RayBundle, mode: RenderMode, stop: Callable[[], bool]) -> FrameRender:
    """What `mode` needs along `rays` (all valid): the main model's render and, for an augmented-depth mode, that
    augmentation's depth, in chunks of `model.hparams.chunk` rays, checking `stop` before each chunk (raises
    `RenderCancelled`)."""

    def before_chunk() -> None:
        if stop():
            raise RenderCancelled

    augmentations = [a for a in model.augmentations if a.name == mode.name] if mode.kind == "augmented_depth" else []
    return model.nerf.render_rays_chunked(rays, int(model.hparams.chunk), augmentations, before_chunk)


def render_picture(
    model,
    rays: RayBundle,
    valid: torch.Tensor,
    width: int,
    height: int,
    mode: RenderMode,
    depth_range: tuple[float, float],
    mask: tuple[torch.Tensor, Views, int] | None = None,
    stop: Callable[[], bool] = lambda: False,
) -> Picture:
    """The picture of `mode` for rays [H * W] (row-major) of which `valid` [H * W] are rendered (the rest is black).

    Args:
        model: a `SimpleNeRF` (its `nerf`, `augmentations`, `hparams.chunk`).
        depth_range: (closest, farthest) depth in scene units at the ends of the colour map.
        mask: for a mask mode, (the mask [h, w] of the nearest train view, the train views, that view's index).
        stop: called between chunks; True abandons the render (`RenderCancelled`).
    """
    if mode.kind == "mask" and mask is None:
        raise ValueError(f"mode {mode.label} needs the mask of a train view")
    n = width * height
    if len(rays) != n or valid.shape != (n,):
        raise ValueError(f"expected {n} rays and flags for {width}x{height}, got {len(rays)}, {tuple(valid.shape)}")
    index = valid.nonzero()[:, 0]
    if len(index) == 0:  # the camera looks away from the scene
        return Picture(rgb=np.zeros((height, width, 3), np.uint8), depth=np.zeros((height, width), np.float32))
    out = render_rays(model, rays[index], mode, stop)

    def full(value: torch.Tensor) -> np.ndarray:
        """Values of the valid rays on the whole picture [H, W, ...] (0 elsewhere)."""
        canvas = value.new_zeros((n, *value.shape[1:]))
        canvas[index] = value
        return canvas.reshape(height, width, *value.shape[1:]).float().cpu().numpy()

    depth = full(out.depth)
    if mode.kind == "rgb":
        picture = to_uint8(full(out.rgb))
    elif mode.kind == "depth":
        picture = depth_picture(depth, depth_range)
    elif mode.kind == "accumulation":
        picture = grey_picture(full(out.accumulation))
    elif mode.kind == "coarse_fine":
        picture = depth_picture(depth, depth_range)
        picture[:, : width // 2] = depth_picture(full(out.coarse_depth), depth_range)[:, : width // 2]
    elif mode.kind == "augmented_depth":
        picture = depth_picture(full(out.augmented_depth[mode.name]), depth_range)
    else:
        values, seen = mask_at_pixels(rays, out.depth, index, mask)
        picture = mask_overlay(full(out.rgb), values.reshape(height, width).cpu().numpy(),
                               seen.reshape(height, width).cpu().numpy())
    if mode.kind != "rgb":
        picture[~valid.reshape(height, width).cpu().numpy()] = 0
    return Picture(rgb=picture, depth=depth)


def mask_at_pixels(
    rays: RayBundle, depth: torch.Tensor, index: torch.Tensor, mask: tuple[torch.Tensor, Views, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """The mask of a train view at each pixel: its rendered surface point o + depth d (depth [V] of the valid rays
    `index`) projected into that view. Returns values [H * W], seen [H * W] bool (False for invalid rays)."""
    values_of_mask, views, view = mask
    points = rays.origins[index] + depth[:, None] * rays.directions[index]
    values, seen = sample_mask(values_of_mask, views, view, points)
    all_values = torch.zeros(len(rays), dtype=values.dtype, device=values.device)
    all_seen = torch.zeros(len(rays), dtype=torch.bool, device=values.device)
    all_values[index], all_seen[index] = values, seen
    return all_values, all_seen
