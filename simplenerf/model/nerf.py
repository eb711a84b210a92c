"""The main NeRF: coarse field -> weights -> hierarchical samples -> fine field (paper Sec. 3).

The coarse and fine fields are injected (`class_path` in YAML; default: the paper's MLP). The coarse `Samples` are
returned with the outputs so that the augmented fields of SimpleNeRF are evaluated at exactly those points, sharing
their cached encodings.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import torch
from jsonargparse.typing import NonNegativeInt, PositiveInt
from torch import nn

from simplenerf.geometry.rays import RayBundle, ndc_to_metric_t
from simplenerf.model.fields import Field, FieldOutputs, RadianceField
from simplenerf.model.rendering import RenderOutputs, composite, compute_weights, cut_near, deltas, density
from simplenerf.model.samplers import hierarchical_samples, stratified_samples
from simplenerf.model.samples import Samples


@dataclass
class NeRFOutputs:
    """The coarse and fine renders of R rays, with the samples they were evaluated at."""

    coarse: RenderOutputs
    fine: RenderOutputs
    coarse_samples: Samples
    fine_samples: Samples

    def samples(self, stage: str) -> Samples:
        """The samples of a stage: "coarse" or "fine"."""
        return self.coarse_samples if stage == "coarse" else self.fine_samples

    def split(self, n: int) -> tuple[NeRFOutputs, NeRFOutputs]:
        """The outputs of the first n rays and of the rest (e.g. a training batch's random and sparse-depth rays)."""
        parts = [self.coarse, self.fine, self.coarse_samples, self.fine_samples]
        return NeRFOutputs(*(p[:n] for p in parts)), NeRFOutputs(*(p[n:] for p in parts))


@dataclass
class FrameRender:
    """A deterministic render of many rays (e.g. a full frame, then [H, W, ...]): the fine field's colour [..., 3],
    depth [...] and accumulation [...], the coarse field's depth [...] and, where asked for, augmentations' depths
    [...] by name (evaluated at the main model's samples, as in training)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    accumulation: torch.Tensor
    coarse_depth: torch.Tensor
    augmented_depth: dict[str, torch.Tensor] = field(default_factory=dict)

    def depth_of(self, name: str) -> torch.Tensor:
        """A depth by render name: "fine", "coarse" or an augmentation's."""
        main = {"fine": self.depth, "coarse": self.coarse_depth}
        return main[name] if name in main else self.augmented_depth[name]

    def reshape(self, height: int, width: int) -> FrameRender:
        """The render of H * W rays as an H x W frame."""
        return FrameRender(self.rgb.reshape(height, width, 3), *(x.reshape(height, width) for x in
                           (self.depth, self.accumulation, self.coarse_depth)),  # fmt: skip
                           {name: d.reshape(height, width) for name, d in self.augmented_depth.items()})


class RendersAlong(Protocol):
    """What `NeRF.render_rays_chunked` asks of an augmentation (`method.augmentations.Augmentation`): its name and
    its render at the main model's samples."""

    name: str

    def render(self, nerf: NeRF, main: NeRFOutputs, randomized: bool) -> RenderOutputs: ...


class NeRF(nn.Module):
    """Coarse and fine radiance fields with stratified + hierarchical sampling in NDC."""

    def __init__(
        self,
        coarse: Field | None = None,
        fine: Field | None = None,
        num_coarse: PositiveInt = 64,
        num_fine: PositiveInt = 128,
        density_noise_std: float = 1.0,
        near: float = 1.0,
        field_chunk: NonNegativeInt = 0,
    ) -> None:
        """
        Args:
            coarse: the coarse field, evaluated at the stratified samples; None: the paper's MLP (`RadianceField()`).
            fine: the fine field, evaluated at all coarse + importance samples; None: the paper's MLP.
            num_coarse: stratified samples per ray for the coarse field.
            num_fine: importance samples per ray added for the fine field (which evaluates all of them).
            density_noise_std: std of the noise added to raw density during training.
            near: the NDC near plane in scene units (1 after the data module's scaling); linked from the data
                module's `near` by the CLI, so it is set in one place.
            field_chunk: sample points per field call (rays are split so that rays x samples stays at most this;
                0: no split). Results are the same; smaller pieces keep every activation below glibc's 32 MiB mmap
                ceiling, so the allocator reuses memory instead of mapping and zero-filling it every step (on a
                2-core CPU a third of a paper step went to page faults), as the release's 16k-point chunks do.
        """
        super().__init__()
        self.num_coarse, self.num_fine = num_coarse, num_fine
        self.density_noise_std = density_noise_std
        self.near, self.field_chunk = near, field_chunk
        self.coarse = coarse if coarse is not None else RadianceField()
        self.fine = fine if fine is not None else RadianceField()

    def make_samples(self, rays: RayBundle, t: torch.Tensor, color: bool = True) -> Samples:
        """Samples at NDC positions t [R, S] along `rays` (`color`: whether any loss reads their colour)."""
        return Samples(
            t=t,
            t_metric=ndc_to_metric_t(t, rays, self.near),
            delta=deltas(t, rays.ndc_directions),
            positions=rays.ndc_origins[:, None, :] + t[..., None] * rays.ndc_directions[:, None, :],
            directions=rays.directions / torch.linalg.vector_norm(rays.directions, dim=-1, keepdim=True),
            color=color,
        )

    def render(self, field: Field, samples: Samples, randomized: bool, min_ndc_z: float | None = None
               ) -> RenderOutputs:
        """Evaluates `field` at `samples` and volume-renders it (density noise only when `randomized`); with
        `min_ndc_z`, the field is empty in front of that NDC z (`rendering.cut_near`)."""
        out = self.evaluate(field, samples)
        # Rendering runs in the precision of the rays, whatever the MLP ran in (e.g. under bf16 autocast).
        raw = out.raw_density.to(samples.t.dtype)
        rgb = out.rgb.to(samples.t.dtype) if samples.color else None
        sigma = density(raw, self.density_noise_std if randomized else 0.0)
        if min_ndc_z is not None:  # after the noise, so that the cut-off samples stay empty
            sigma = cut_near(sigma, samples.positions[..., 2], min_ndc_z)
        return composite(compute_weights(sigma, samples.delta), rgb, samples.t_metric)

    def evaluate(self, field: Field, samples: Samples) -> FieldOutputs:
        """`field(samples)`, in pieces of at most `field_chunk` sample points (whole rays)."""
        rays, per_ray = samples.t.shape
        step = max(self.field_chunk // per_ray, 1) if self.field_chunk else rays
        if step >= rays:
            return field(samples)
        parts = [field(samples[start : start + step]) for start in range(0, rays, step)]
        rgb = torch.cat([p.rgb for p in parts]) if samples.color else None
        return FieldOutputs(torch.cat([p.raw_density for p in parts]), rgb)

    def forward(self, rays: RayBundle, randomized: bool, color: bool = True) -> NeRFOutputs:
        """Coarse then fine rendering. `randomized`: jittered samples and density noise (training). `color` False:
        depth, accumulation and weights only (rgb None; the fields may skip their colour branches), for rays whose
        losses read depth only; the same depths either way."""
        t_coarse = stratified_samples(len(rays), self.num_coarse, randomized, like=rays.ndc_origins)
        coarse_samples = self.make_samples(rays, t_coarse, color)
        coarse = self.render(self.coarse, coarse_samples, randomized)
        t_fine = hierarchical_samples(t_coarse, coarse.weights, self.num_fine, deterministic=not randomized)
        fine_samples = self.make_samples(rays, t_fine, color)
        fine = self.render(self.fine, fine_samples, randomized)
        return NeRFOutputs(coarse=coarse, fine=fine, coarse_samples=coarse_samples, fine_samples=fine_samples)

    @torch.no_grad()
    def render_rays_chunked(
        self,
        rays: RayBundle,
        chunk: int,
        augmentations: Sequence[RendersAlong] = (),
        before_chunk: Callable[[], None] | None = None,
    ) -> FrameRender:
        """Deterministic rendering of many rays (a full frame) in chunks, so memory is bounded at any resolution: the
        one full-frame renderer (validation, test, predict, videos, exports, held-out depth, reliability maps, the
        viewer).

        Args:
            augmentations: augmentations whose depths to render too, at the main model's samples.
            before_chunk: called before each chunk; it may raise to abandon the render (the viewer's cancel).

        Returns:
            rgb [R, 3], depth [R], accumulation [R] of the fine field, coarse_depth [R] and augmented_depth {name: [R]}.
        """
        # Only the per-ray results of a chunk are kept: its samples and weights ([chunk, S] each) are freed before
        # the next chunk, so the peak does not grow with the number of rays times the samples per ray.
        parts: list[FrameRender] = []
        for start in range(0, len(rays), chunk):
            if before_chunk is not None:
                before_chunk()
            main = self(rays[start : start + chunk], randomized=False)
            augmented = {aug.name: aug.render(self, main, False).depth for aug in augmentations}
            parts.append(FrameRender(main.fine.rgb, main.fine.depth, main.fine.accumulation, main.coarse.depth,
                                     augmented))
            del main
        return FrameRender(*(torch.cat([getattr(p, k) for p in parts]) for k in ("rgb", "depth", "accumulation",
                                                                                   "coarse_depth")),
                           {aug.name: torch.cat([p.augmented_depth[aug.name] for p in parts]) for aug in augmentations})


def mlp_nerf(num_coarse: int = 64, num_fine: int = 128, density_noise_std: float = 1.0, near: float = 1.0,
             **field_args) -> NeRF:
    """A NeRF whose coarse and fine fields are `RadianceField(**field_args)` (built coarse first), for Python use."""
    coarse, fine = RadianceField(**field_args), RadianceField(**field_args)
    return NeRF(coarse, fine, num_coarse, num_fine, density_noise_std, near)
