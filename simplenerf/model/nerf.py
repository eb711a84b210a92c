"""The main NeRF: coarse field -> weights -> hierarchical samples -> fine field (paper Sec. 3).

`Samples` holds everything about a set of sample points that does not depend on the field evaluated there
(positions, intervals, metric depths, encodings). The coarse samples are returned with the outputs so that the
augmented fields of SimpleNeRF are evaluated at exactly those points without recomputing any of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from simplenerf.geometry.rays import RayBundle, ndc_to_metric_t
from simplenerf.model.encodings import positional_encoding
from simplenerf.model.fields import RadianceField
from simplenerf.model.rendering import RenderOutputs, composite, compute_weights, deltas, density
from simplenerf.model.samplers import hierarchical_samples, stratified_samples


@dataclass
class Samples:
    """Sample points along a batch of R rays, S per ray, shared by every field evaluated there."""

    t: torch.Tensor  # [R, S] NDC positions in [0, 1]
    t_metric: torch.Tensor  # [R, S] camera z-depths
    delta: torch.Tensor  # [R, S] NDC interval lengths
    points_enc: torch.Tensor  # [R, S, 3(2 L_p + 1)] gamma(p, 0, L_p) of the NDC points
    dirs_enc: torch.Tensor  # [R, 3(2 L_v + 1)] gamma(v, 0, L_v) of the unit view directions


@dataclass
class NeRFOutputs:
    coarse: RenderOutputs
    fine: RenderOutputs
    coarse_samples: Samples
    fine_samples: Samples


class NeRF(nn.Module):
    """Coarse and fine radiance fields with stratified + hierarchical sampling in NDC."""

    def __init__(
        self,
        num_coarse: int = 64,
        num_fine: int = 128,
        point_bands: int = 10,
        view_bands: int = 4,
        num_layers: int = 8,
        width: int = 256,
        skip_layer: int | None = 5,
        density_noise_std: float = 1.0,
        near: float = 1.0,
    ) -> None:
        """
        Args:
            num_coarse: stratified samples per ray for the coarse field.
            num_fine: importance samples per ray added for the fine field (which evaluates all of them).
            point_bands: L_p, positional-encoding bands of sample points.
            view_bands: L_v, positional-encoding bands of view directions.
            num_layers: trunk layers of the coarse and fine fields.
            width: trunk width of the coarse and fine fields.
            skip_layer: trunk layer that receives the encoded point again (5: before the 6th layer); None: no skip.
            density_noise_std: std of the noise added to raw density during training.
            near: the NDC near plane in scene units (1 after the data module's scaling).
        """
        super().__init__()
        self.num_coarse, self.num_fine = num_coarse, num_fine
        self.point_bands, self.view_bands = point_bands, view_bands
        self.density_noise_std = density_noise_std
        self.near = near
        size = {"num_layers": num_layers, "width": width, "skip_layer": skip_layer}
        self.coarse = RadianceField(point_bands, view_bands, **size)
        self.fine = RadianceField(point_bands, view_bands, **size)

    def make_samples(self, rays: RayBundle, t: torch.Tensor, dirs_enc: torch.Tensor | None = None) -> Samples:
        """Samples at NDC positions t [R, S] along `rays`."""
        points = rays.ndc_origins[:, None, :] + t[..., None] * rays.ndc_directions[:, None, :]
        if dirs_enc is None:
            view_dirs = rays.directions / torch.linalg.vector_norm(rays.directions, dim=-1, keepdim=True)
            dirs_enc = positional_encoding(view_dirs, self.view_bands)
        return Samples(
            t=t,
            t_metric=ndc_to_metric_t(t, rays, self.near),
            delta=deltas(t, rays.ndc_directions),
            points_enc=positional_encoding(points, self.point_bands),
            dirs_enc=dirs_enc,
        )

    def render(self, field: nn.Module, samples: Samples, randomized: bool) -> RenderOutputs:
        """Evaluates `field` at `samples` and volume-renders it (density noise only when `randomized`)."""
        out = field(samples.points_enc, samples.dirs_enc)
        # Rendering runs in the precision of the rays, whatever the MLP ran in (e.g. under bf16 autocast).
        raw, rgb = out.raw_density.to(samples.t.dtype), out.rgb.to(samples.t.dtype)
        sigma = density(raw, self.density_noise_std if randomized else 0.0)
        return composite(compute_weights(sigma, samples.delta), rgb, samples.t_metric)

    def forward(self, rays: RayBundle, randomized: bool) -> NeRFOutputs:
        """Coarse then fine rendering. `randomized`: jittered samples and density noise (training)."""
        t_coarse = stratified_samples(len(rays), self.num_coarse, randomized, like=rays.ndc_origins)
        coarse_samples = self.make_samples(rays, t_coarse)
        coarse = self.render(self.coarse, coarse_samples, randomized)
        t_fine = hierarchical_samples(t_coarse, coarse.weights, self.num_fine, deterministic=not randomized)
        fine_samples = self.make_samples(rays, t_fine, dirs_enc=coarse_samples.dirs_enc)
        fine = self.render(self.fine, fine_samples, randomized)
        return NeRFOutputs(coarse=coarse, fine=fine, coarse_samples=coarse_samples, fine_samples=fine_samples)

    @torch.no_grad()
    def render_rays_chunked(self, rays: RayBundle, chunk: int) -> dict[str, torch.Tensor]:
        """Deterministic rendering of many rays (a full frame) in chunks, so memory is bounded at any resolution.

        Returns:
            rgb [R, 3], depth [R], accumulation [R] of the fine field, and coarse_depth [R].
        """
        parts: dict[str, list[torch.Tensor]] = {"rgb": [], "depth": [], "accumulation": [], "coarse_depth": []}
        for start in range(0, len(rays), chunk):
            out = self(rays[start : start + chunk], randomized=False)
            parts["rgb"].append(out.fine.rgb)
            parts["depth"].append(out.fine.depth)
            parts["accumulation"].append(out.fine.accumulation)
            parts["coarse_depth"].append(out.coarse.depth)
        return {k: torch.cat(v) for k, v in parts.items()}
