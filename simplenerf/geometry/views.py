"""Posed views: the one type for a set of cameras with their images (train views, test frames, a whole scene).

The reliability masks, the visibility masks, the data modules and the trajectories all take a `Views`. Camera and
pixel conventions are those of `simplenerf.geometry.rays`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from simplenerf.geometry.rays import RayBundle, make_rays, pixel_rays, project


def nearest_views(c2w: torch.Tensor) -> torch.Tensor:
    """For each view, the other view whose camera centre is closest (ties: the lowest index).

    Args:
        c2w: [V, 3, 4] camera-to-world matrices, V >= 2.

    Returns:
        [V] long indices into the same views, never the view itself.
    """
    if c2w.ndim != 3 or c2w.shape[0] < 2:
        raise ValueError(f"nearest_views needs at least 2 views of c2w [V, 3, 4], got shape {tuple(c2w.shape)}")
    centres = c2w[:, :3, 3]
    distance = (centres[:, None] - centres[None]).square().sum(-1)  # [V, V]; exact, unlike cdist's matmul form
    distance.fill_diagonal_(math.inf)
    return distance.argmin(dim=1)


@dataclass(eq=False)
class Views:
    """V posed views of one scene, all H x W."""

    images: torch.Tensor  # [V, H, W, 3] in [0, 1]
    intrinsics: torch.Tensor  # [V, 3, 3]
    c2w: torch.Tensor  # [V, 3, 4]
    names: list[str]  # [V] file names, for outputs
    depths: torch.Tensor | None = None  # [V, H, W] reference camera z-depth, when known
    _nearest: torch.Tensor | None = field(default=None, repr=False)

    @property
    def height(self) -> int:
        return self.images.shape[1]

    @property
    def width(self) -> int:
        return self.images.shape[2]

    def __len__(self) -> int:
        return self.images.shape[0]

    @property
    def nearest(self) -> torch.Tensor:
        """[V] long: `nearest_views` of these views, computed once."""
        if self._nearest is None:
            self._nearest = nearest_views(self.c2w)
        return self._nearest

    def pixel_rays(self, view: torch.Tensor, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World rays (origins, directions [R, 3]) through pixels uv [R, 2] of views view [R]."""
        return pixel_rays(self.intrinsics[view], self.c2w[view], uv)

    def project(self, points: torch.Tensor, view: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points [R, 3] into views view [R]: pixels uv [R, 2] and camera z-depths [R] (> 0 in front)."""
        return project(points, self.intrinsics[view], self.c2w[view])

    def rays(self, view: torch.Tensor, uv: torch.Tensor, near: float) -> RayBundle:
        """Rays through pixels uv [R, 2] of views view [R] in both parametrisations (NDC with `near`)."""
        return make_rays(self.intrinsics[view], self.c2w[view], uv, self.width, self.height, near)

    def subset(self, indices: list[int]) -> Views:
        """The views at `indices` (views of a scene -> views of one split)."""
        return Views(
            images=self.images[indices],
            intrinsics=self.intrinsics[indices],
            c2w=self.c2w[indices],
            names=[self.names[i] for i in indices],
            depths=None if self.depths is None else self.depths[indices],
        )

    def to(self, device: torch.device | str) -> Views:
        """These views with every tensor on `device`."""
        moved = {k: getattr(self, k).to(device) for k in ("images", "intrinsics", "c2w")}
        depths = None if self.depths is None else self.depths.to(device)
        nearest = None if self._nearest is None else self._nearest.to(device)
        return replace(self, **moved, depths=depths, _nearest=nearest)
