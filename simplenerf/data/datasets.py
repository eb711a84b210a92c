"""Ray datasets shared by every scene format: random training rays and full frames.

A `Views` holds images and cameras of a set of frames; the datasets index into it, so no image is copied per step.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from simplenerf.geometry.rays import make_rays, pixel_grid


@dataclass
class Views:
    """Frames of one scene, as tensors (see `simplenerf.geometry.rays` for the camera conventions)."""

    images: torch.Tensor  # [V, H, W, 3] in [0, 1]
    intrinsics: torch.Tensor  # [V, 3, 3]
    c2w: torch.Tensor  # [V, 3, 4]
    names: list[str]  # [V] file names, for outputs
    depths: torch.Tensor | None = None  # [V, H, W] reference camera z-depth, when known

    @property
    def height(self) -> int:
        return self.images.shape[1]

    @property
    def width(self) -> int:
        return self.images.shape[2]

    def __len__(self) -> int:
        return self.images.shape[0]

    def rays(self, view: torch.Tensor, uv: torch.Tensor, near: float) -> dict[str, torch.Tensor]:
        """Ray fields for pixels uv [R, 2] of views view [R] (see `rays.make_rays`)."""
        return make_rays(self.intrinsics[view], self.c2w[view], uv, self.width, self.height, near)


@dataclass
class SparseDepthPool:
    """Pixels of the training views with a sparse (SfM) depth, one entry per observation. P entries."""

    view: torch.Tensor  # [P] index into the training views
    uv: torch.Tensor  # [P, 2] continuous pixel coordinates (keypoint locations)
    depth: torch.Tensor  # [P] camera z-depth, scene units
    weight: torch.Tensor  # [P] per-point loss weight (1, or DS-NeRF's reprojection-error weight)

    def __len__(self) -> int:
        return self.view.shape[0]


def _rank() -> int:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank()
    return 0


class RandomRays(IterableDataset):
    """An endless stream of batches of random training rays from a shuffled pool of all training pixels.

    Epoch-style: every pixel is drawn once before the pool is reshuffled. Each distributed rank and data-loader
    worker draws from its own generator, so they see different rays. With a sparse-depth pool, every batch also
    carries `sparse_rays_per_batch` rays drawn (with replacement) from it, under keys prefixed `sparse_`.
    """

    def __init__(
        self,
        views: Views,
        rays_per_batch: int,
        near: float,
        seed: int = 0,
        sparse: SparseDepthPool | None = None,
        sparse_rays_per_batch: int = 0,
    ) -> None:
        num_pixels = len(views) * views.height * views.width
        if rays_per_batch > num_pixels:
            raise ValueError(f"rays_per_batch={rays_per_batch} exceeds the {num_pixels} training pixels")
        self.views, self.rays_per_batch, self.near, self.seed = views, rays_per_batch, near, seed
        self.sparse, self.sparse_rays_per_batch = sparse, sparse_rays_per_batch if sparse is not None else 0

    def sparse_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        assert self.sparse is not None
        index = torch.randint(len(self.sparse), (self.sparse_rays_per_batch,), generator=generator)
        view = self.sparse.view[index]
        batch = self.views.rays(view, self.sparse.uv[index], self.near)
        batch.update(depth=self.sparse.depth[index], weight=self.sparse.weight[index], view=view)
        return {f"sparse_{k}": v for k, v in batch.items()}

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        worker = get_worker_info()
        generator = torch.Generator().manual_seed(self.seed + 1000 * _rank() + (worker.id if worker else 0))
        h, w = self.views.height, self.views.width
        num_pixels = len(self.views) * h * w
        while True:
            order = torch.randperm(num_pixels, generator=generator)
            for start in range(0, num_pixels - self.rays_per_batch + 1, self.rays_per_batch):
                index = order[start : start + self.rays_per_batch]
                view, pixel = index // (h * w), index % (h * w)
                uv = torch.stack([pixel % w, pixel // w], dim=-1)
                batch = self.views.rays(view, uv, self.near)
                batch.update(rgb=self.views.images[view, uv[:, 1], uv[:, 0]], view=view, uv=uv)
                if self.sparse_rays_per_batch:
                    batch.update(self.sparse_batch(generator))
                yield batch


class Frames(Dataset):
    """Full frames, one item per frame: every pixel's ray in row-major order, the image and the reference depth."""

    def __init__(self, views: Views, near: float, indices: list[int] | None = None) -> None:
        self.views, self.near = views, near
        self.indices = list(range(len(views))) if indices is None else indices

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        index = self.indices[i]
        h, w = self.views.height, self.views.width
        item = self.views.rays(torch.full((h * w,), index), pixel_grid(h, w), self.near)
        item.update(rgb=self.views.images[index].reshape(-1, 3), index=index, name=self.views.names[index])
        item.update(height=h, width=w)
        if self.views.depths is not None:
            item["depth"] = self.views.depths[index].reshape(-1)
        return item
