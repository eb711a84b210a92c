"""Typed batches: what the data modules hand to the model.

- `RayBatch`: R rays of train pixels with their colours, views and pixels (what the reliability masks need).
- `SparseDepthBatch`: a `RayBatch` at pixels with an SfM depth, plus the depths and their loss weights.
- `UnseenPatches`: P square patches of rays from cameras no train view has (RegNeRF's unobserved viewpoints).
- `TrainingBatch`: one iteration's random rays and, when on, its sparse-depth rays and unseen patches.
- `Frame`: every pixel of one full frame (validation, test, predict), row-major.

All are dataclasses, which Lightning moves between devices as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TypeVar

import torch

from simplenerf.geometry.rays import RayBundle

# typing.Self needs Python 3.11; the package supports 3.10 (pyproject).
Batch = TypeVar("Batch", bound="RayBatch")


@dataclass
class RayBatch:
    """R training rays."""

    rays: RayBundle
    rgb: torch.Tensor  # [R, 3] ground-truth colours in [0, 1]
    view: torch.Tensor  # [R] long, index into the train views
    uv: torch.Tensor  # [R, 2] pixel (column, row), continuous for SfM keypoints

    def __len__(self) -> int:
        return len(self.rays)

    def __getitem__(self: Batch, index: slice) -> Batch:
        """The rays at `index` (a sub-batch), with every per-ray field."""
        return type(self)(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


@dataclass
class SparseDepthBatch(RayBatch):
    """R rays at pixels with a sparse (SfM) depth."""

    depth: torch.Tensor  # [R] camera z-depth, scene units
    weight: torch.Tensor  # [R] per-point loss weight


@dataclass
class UnseenPatches:
    """P patches of size x size rays from unseen cameras (`geometry.unseen`), each row-major (v outer, u inner), the
    patches one after another: ray p * size^2 + i * size + j is row i, column j of patch p. No colour: no photo."""

    rays: RayBundle  # [P * size * size]
    size: int

    def __len__(self) -> int:
        return len(self.rays)

    @property
    def count(self) -> int:
        """P, the number of patches."""
        return len(self.rays) // self.size**2


@dataclass
class TrainingBatch:
    """One training iteration: random rays, and sparse-depth rays and unseen patches when the data module serves
    them."""

    random: RayBatch
    sparse: SparseDepthBatch | None = None
    unseen: UnseenPatches | None = None

    @property
    def rays(self) -> RayBundle:
        """The random rays followed by the sparse-depth rays: the model renders all of them in one pass."""
        return self.random.rays if self.sparse is None else self.random.rays.cat(self.sparse.rays)


@dataclass
class Frame:
    """Every pixel of one frame, row-major (v outer, u inner)."""

    rays: RayBundle  # H * W rays
    rgb: torch.Tensor  # [H * W, 3] ground truth in [0, 1]
    depth: torch.Tensor | None  # [H * W] reference camera z-depth, when the scene has it
    index: int  # frame index in the scene
    name: str  # frame file name (outputs are named after it)
    height: int
    width: int
