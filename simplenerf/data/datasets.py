"""Ray datasets shared by every scene format: random training rays and full frames.

The datasets index into a `Views` (images and cameras of a set of frames), so no image is copied per step.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from simplenerf.data.batches import Frame, RayBatch, SparseDepthBatch, TrainingBatch, UnseenPatches
from simplenerf.geometry.rays import make_rays, pixel_grid
from simplenerf.geometry.unseen import unseen_cameras
from simplenerf.geometry.views import Views


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


def shuffled_pool(size: int, batch: int, generator: torch.Generator) -> Iterator[torch.Tensor]:
    """Endless batches [batch] of indices into a pool of `size` entries: consecutive slices of successive random
    permutations, so every entry is drawn once per pass; a batch may span two passes (and several, if the pool is
    smaller than a batch)."""
    if size < 1:
        raise ValueError("the pool is empty")
    if batch < 1:
        raise ValueError(f"a batch needs at least one entry, got {batch}")
    buffer = torch.empty(0, dtype=torch.long)
    while True:
        while len(buffer) < batch:
            buffer = torch.cat([buffer, torch.randperm(size, generator=generator)])
        yield buffer[:batch]
        buffer = buffer[batch:]


def unseen_patch_problem(views: Views, size: int) -> str | None:
    """Why `views` cannot give unseen patches of `size` pixels (they need two views to place cameras around, and fit
    the image), or None."""
    if len(views) >= 2 and 2 <= size <= min(views.height, views.width):
        return None
    return (f"unseen patches of {size} px need at least 2 train views at least that large and a size of at least 2, "
            f"got {len(views)} of {views.width}x{views.height}")


class RandomRays(IterableDataset):
    """An endless stream of batches of random training rays from a shuffled pool of all training pixels.

    Epoch-style: every pixel is drawn once before the pool is reshuffled. Each distributed rank and data-loader
    worker draws from its own generator, so they see different rays. With a sparse-depth pool, every batch also
    carries `sparse_rays_per_batch` rays from it (`TrainingBatch.sparse`), drawn epoch-style as well: every SfM
    observation once before that pool is reshuffled (batches run across reshuffles when the pool is small). With
    `unseen_patches`, every batch also carries that many square patches of rays from random unseen cameras
    (`TrainingBatch.unseen`), drawn from a generator of their own, so that they leave the other rays' order as it is.
    """

    def __init__(
        self,
        views: Views,
        rays_per_batch: int,
        near: float,
        seed: int = 0,
        sparse: SparseDepthPool | None = None,
        sparse_rays_per_batch: int = 0,
        start_batch: int = 0,
        unseen_patches: int = 0,
        patch_size: int = 8,
        unseen_spread: float = 1.0,
    ) -> None:
        """
        Args:
            views: the training views.
            rays_per_batch: random rays per batch (>= 1).
            near: NDC near plane of the rays.
            seed: seed of the order (each rank and worker adds its own offset).
            sparse: the sparse-depth pool, or None.
            sparse_rays_per_batch: rays per batch from `sparse` (>= 0; 0: none).
            start_batch: batches already drawn by the run (a resume): the stream continues after them, in the order
                the run would have drawn them.
            unseen_patches: patches per batch from unseen cameras (>= 0; 0: none; needs at least 2 views).
            patch_size: their side in pixels (>= 2).
            unseen_spread: how far the unseen cameras leave the train centres' hull (`geometry.unseen`).
        """
        num_pixels = len(views) * views.height * views.width
        checks = (("rays_per_batch", rays_per_batch, 1), ("sparse_rays_per_batch", sparse_rays_per_batch, 0),
                  ("start_batch", start_batch, 0), ("unseen_patches", unseen_patches, 0), ("patch_size", patch_size, 2))
        for option, value, least in checks:
            if not isinstance(value, int) or value < least:
                raise ValueError(f"{option} must be an integer >= {least}, got {value!r}")
        if rays_per_batch > num_pixels:
            raise ValueError(f"rays_per_batch={rays_per_batch} exceeds the {num_pixels} training pixels")
        self.views, self.rays_per_batch, self.near, self.seed = views, rays_per_batch, near, seed
        self.sparse, self.sparse_rays_per_batch = sparse, sparse_rays_per_batch if sparse is not None else 0
        if self.sparse_rays_per_batch and len(sparse) < 1:
            raise ValueError("the sparse-depth pool is empty")
        self.start_batch = start_batch
        if unseen_patches and (problem := unseen_patch_problem(views, patch_size)):
            raise ValueError(problem)
        self.unseen_patches, self.patch_size, self.unseen_spread = unseen_patches, patch_size, unseen_spread

    def sparse_batch(self, index: torch.Tensor) -> SparseDepthBatch:
        """The sparse-depth rays of pool entries `index` [R]."""
        assert self.sparse is not None
        view, uv = self.sparse.view[index], self.sparse.uv[index]
        # The keypoint's nearest pixel colour (no loss uses it; the batch type has colours).
        u = uv[:, 0].round().long().clamp(0, self.views.width - 1)
        v = uv[:, 1].round().long().clamp(0, self.views.height - 1)
        rgb = self.views.images[view, v, u]
        return SparseDepthBatch(self.views.rays(view, uv, self.near), rgb, view, uv, self.sparse.depth[index],
                                self.sparse.weight[index])

    def _indices(self, generator: torch.Generator) -> Iterator[tuple[torch.Tensor, torch.Tensor | None]]:
        """Endless (pixel indices [R] into the views' pixels, sparse pool indices [R_s] or None) per batch."""
        sparse = shuffled_pool(len(self.sparse), self.sparse_rays_per_batch, generator) if self.sparse_rays_per_batch \
            else None
        num_pixels = len(self.views) * self.views.height * self.views.width
        while True:
            order = torch.randperm(num_pixels, generator=generator)
            for start in range(0, num_pixels - self.rays_per_batch + 1, self.rays_per_batch):
                yield order[start : start + self.rays_per_batch], None if sparse is None else next(sparse)

    def _unseen(self, generator: torch.Generator) -> Iterator[UnseenPatches | None]:
        """Endless unseen patches per batch (None when off): random cameras, each with one patch at a random place of
        the train views' image size and intrinsics (those of the first train view)."""
        size, (h, w) = self.patch_size, (self.views.height, self.views.width)
        offsets = pixel_grid(size, size)  # [size^2, 2] (column, row), row-major
        while True:
            if not self.unseen_patches:
                yield None
                continue
            c2w = unseen_cameras(self.views.c2w, self.unseen_patches, self.unseen_spread, generator)
            corner = torch.stack([torch.randint(0, w - size + 1, (self.unseen_patches,), generator=generator),
                                  torch.randint(0, h - size + 1, (self.unseen_patches,), generator=generator)], -1)
            uv = (corner[:, None] + offsets[None]).reshape(-1, 2)
            c2w = c2w.repeat_interleave(size * size, dim=0)
            yield UnseenPatches(make_rays(self.views.intrinsics[:1], c2w, uv, w, h, self.near), size)

    def __iter__(self) -> Iterator[TrainingBatch]:
        worker = get_worker_info()
        seed = self.seed + 1000 * _rank() + (worker.id if worker else 0)
        indices = self._indices(torch.Generator().manual_seed(seed))
        unseen = self._unseen(torch.Generator().manual_seed(seed + 500))
        # A resume continues the order: the data loader takes batches from its workers in turn, so worker w drew
        # every num_workers-th of the batches drawn so far, starting with the w-th.
        workers, index = (worker.num_workers, worker.id) if worker else (1, 0)
        for _ in range(max(0, self.start_batch - index + workers - 1) // workers):
            next(indices), next(unseen)
        h, w = self.views.height, self.views.width
        for pixels, sparse in indices:
            view, pixel = pixels // (h * w), pixels % (h * w)
            uv = torch.stack([pixel % w, pixel // w], dim=-1)
            rgb = self.views.images[view, uv[:, 1], uv[:, 0]]
            random = RayBatch(self.views.rays(view, uv, self.near), rgb, view, uv)
            yield TrainingBatch(random, None if sparse is None else self.sparse_batch(sparse), next(unseen))


class Frames(Dataset):
    """Full frames, one item per frame: every pixel's ray in row-major order, the image and the reference depth."""

    def __init__(self, views: Views, near: float, indices: list[int] | None = None) -> None:
        self.views, self.near = views, near
        self.indices = list(range(len(views))) if indices is None else indices

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> Frame:
        index = self.indices[i]
        h, w = self.views.height, self.views.width
        rays = self.views.rays(torch.full((h * w,), index), pixel_grid(h, w), self.near)
        depth = None if self.views.depths is None else self.views.depths[index].reshape(-1)
        return Frame(rays, self.views.images[index].reshape(-1, 3), depth, index, self.views.names[index], h, w)
