"""A grid radiance field: K-Planes (Fridovich-Keil et al., CVPR 2023) over the NDC box of forward-facing scenes.

Why K-Planes (benchmarks/speed/grid_cost.py; docs/results.md "Grid backbone"): of the pure-PyTorch grids tried on
the 2-core CPU, its forward + backward + Adam step per sample point was among the cheapest (about 25x cheaper than
the paper's 8x256 MLP), the parameters Adam updates each step stay small (planes, not volumes), it was shown on LLFF
in NDC, and its multi-scale planes give SimpleNeRF's points augmentation directly: the same field with its coarsest
scales only.

Naming, used throughout:
- x, y, z: NDC coordinates of the sample points (`Samples.positions`); z is in [-1, 1), x and y are [-1, 1] across
  the reference (average) camera's image, and other cameras see past that: LLFF frames' frusta reach |x| 1.2-1.8 and
  |y| 1.1-1.7 (docs/results.md, "Where the blur and the streaks come from", 36). The planes span
  [-extent_x, extent_x] x [-extent_y, extent_y] x [-1, 1] (`KPlanesField(extent=...)`); points outside take the
  border values of the planes, constant along the axis they leave by: a horizontal streak where x leaves.
- plane: a 2D feature grid [1, C, H, W] over two of the axes: xy (W = x, H = y), xz (W = x, H = z), yz (W = y,
  H = z). Node i of an axis with n nodes sits at e (-1 + 2 i / (n - 1)), e the axis' extent (1 for z;
  `align_corners=True`): values at nodes are exact, bilinear in between.
- scale: the three planes at one resolution; the feature of a point at a scale is the Hadamard product of its three
  plane interpolations (C values); the scales' features are concatenated (K-Planes' "multiscale" features).
- decoder: a small MLP from the features to density (through a truncated exponential, as K-Planes and Instant-NGP;
  so the raw density is >= 0 and the NeRF's ReLU leaves it unchanged) and a geometry feature, then a colour MLP on
  [geometry feature, gamma(view direction)] (without the direction when `view_dependent=False`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from simplenerf.model.encodings import encoded_dim
from simplenerf.model.fields import Field, FieldOutputs
from simplenerf.model.samples import Samples

# (width axis, height axis) of each plane of a scale, as indices into (x, y, z).
PLANE_AXES = ((0, 1), (0, 2), (1, 2))
PLANE_NAMES = ("xy", "xz", "yz")


class _TruncExp(torch.autograd.Function):
    """exp(x) whose gradient uses exp(clamp(x, max=15)): large densities stay trainable without exploding steps. The
    value is exp(x) up to a factor e below the largest finite one of x's dtype (x clamped at its log - 1): an infinite
    density times a zero interval would make the ray's weights NaN (a 3600-step fern fit, docs/results.md "Grid
    backbone")."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x.clamp(max=math.log(torch.finfo(x.dtype).max) - 1.0))

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15.0))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """exp with a clamped gradient (Instant-NGP's density activation)."""
    return _TruncExp.apply(x)


def sample_plane(plane: torch.Tensor, coords: torch.Tensor, parts: int | None = None) -> torch.Tensor:
    """Bilinear interpolation of one plane.

    On the CPU, PyTorch's `grid_sample` and its backward divide their work among threads by batch entry only, so a
    plane sampled as one batch entry runs on one core (its backward was 30-37% of a `simplerf_images4.yaml` step on 2
    threads; docs/benchmarks.md "The grid step on both cores"). Where the plane has at most as many nodes as there are
    points, the points are cut into one batch entry per thread over the same plane (`expand`, no copy); the entries'
    gradients are summed, which costs a pass over a copy of the plane per thread, hence the bound. Values are the
    same; a node's gradient sums the same terms in another order (float rounding).

    Args:
        plane: [1, C, H, W]. coords: [P, 2] (width coordinate, height coordinate) in [-1, 1] (node 0 at -1, node
            n - 1 at +1; outside: the border value).
        parts: batch entries to cut the points into (None: `split_points`' choice; 1: one entry).

    Returns:
        [C, P].
    """
    grid = coords.to(plane.dtype)
    points = grid.shape[0]
    parts = split_points(plane, points) if parts is None else parts
    pad = -points % parts  # repeats the last point; its values are dropped, so it adds no gradient
    if pad:
        grid = torch.cat([grid, grid[-1:].expand(pad, 2)])
    out = F.grid_sample(plane.expand(parts, -1, -1, -1), grid.view(parts, -1, 1, 2), mode="bilinear",
                        padding_mode="border", align_corners=True)  # [parts, C, P / parts, 1]
    return out.transpose(0, 1).reshape(plane.shape[1], -1)[:, :points]  # a view when parts is 1


def split_points(plane: torch.Tensor, points: int) -> int:
    """Batch entries to cut `points` samples of `plane` [1, C, H, W] into: one per intra-op thread on the CPU when
    the plane has at most `points` nodes (H W), else 1 (one entry; also on a GPU, whose kernel spreads the points)."""
    threads = torch.get_num_threads()
    if plane.device.type != "cpu" or threads < 2 or points < 2 * threads:
        return 1
    return threads if plane.shape[-2] * plane.shape[-1] <= points else 1


def plane_tv(plane: torch.Tensor) -> torch.Tensor:
    """K-Planes' total variation of one plane [1, C, H, W]: 2 (mean squared difference along H + along W)."""
    return _PlaneTV.apply(plane)


class _PlaneTV(torch.autograd.Function):
    """`plane_tv` with its gradient written into one buffer. Autograd's graph of the same formula (per axis two
    slices, a difference, a square and a mean) makes about 25 passes over a copy of the plane in the backward (the
    mean's gradient materialised, the square's, a zero-filled plane per slice, a negation, four additions): on the
    1024-node plane of `simplerf_images4.yaml` about a fifth of a step. Here: two differences and two dot products
    forward, one product and three fused multiply-adds backward (docs/benchmarks.md "The grid step on both cores")."""

    @staticmethod
    def forward(ctx, plane: torch.Tensor) -> torch.Tensor:
        d_h = plane[..., 1:, :] - plane[..., :-1, :]  # [1, C, H - 1, W]
        d_w = plane[..., :, 1:] - plane[..., :, :-1]  # [1, C, H, W - 1]
        ctx.save_for_backward(d_h, d_w)
        ctx.plane_shape = plane.shape
        sq_h = torch.dot(d_h.reshape(-1), d_h.reshape(-1))
        sq_w = torch.dot(d_w.reshape(-1), d_w.reshape(-1))
        return 2.0 * (sq_h / d_h.numel() + sq_w / d_w.numel())

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        d_h, d_w = ctx.saved_tensors
        c_h, c_w = grad * (4.0 / d_h.numel()), grad * (4.0 / d_w.numel())  # d/dd of 2 mean(d^2): 4 d / n
        out = d_h.new_empty(ctx.plane_shape)
        # node i is the + end of difference i - 1 and the - end of difference i (along each axis)
        torch.mul(d_h, c_h, out=out[..., 1:, :])
        out[..., :1, :].zero_()
        out[..., :-1, :].addcmul_(d_h, -c_h)
        out[..., :, 1:].addcmul_(d_w, c_w)
        out[..., :, :-1].addcmul_(d_w, -c_w)
        return out


class KPlanesField(Field):
    """Multi-scale K-Planes (3 planes per scale, Hadamard product, scales concatenated) + a small MLP decoder."""

    def __init__(
        self,
        resolutions: list[int] | None = None,
        depth_resolutions: list[int] | None = None,
        features: int = 16,
        density_scales: int | None = None,
        density_features: int | None = None,
        residual_scales_to_color: bool = False,
        view_dependent: bool = True,
        view_bands: int = 4,
        hidden: int = 64,
        geometry_features: int = 15,
        tv_weight: float = 1e-4,
        depth_tv_scale: float = 1.0,
        init_range: tuple[float, float] = (0.1, 0.5),
        density_shift: float = 0.0,
        extent: tuple[float, float] = (1.0, 1.0),
    ) -> None:
        """
        Args:
            resolutions: nodes along x and y at each scale, coarsest first (None: [64, 128, 256]). The points
                augmentation is the same field with the first (coarsest) scales only.
            depth_resolutions: nodes along z at each scale (None: the same as `resolutions`).
            features: C, feature channels of every plane.
            density_scales: the density MLP sees the features of the first (coarsest) `density_scales` scales only;
                None: all (the main field). The grid's analogue of `RadianceField(density_bands=...)`.
            density_features: of each of those scales, the density MLP sees the first `density_features` channels
                only (None: all `features`): a lower-rank density, as Simple-TensoRF's points augmentation has 4
                density components per plane where its main model has 16, with the same colour components
                (Simple-RF release, runs/training/train1546/Configs.json, `num_components_density`).
            residual_scales_to_color: feed what the density MLP does not see (the other, finer scales; the channels
                beyond `density_features`) to the colour MLP, as `RadianceField(residual_bands_to_color=True)` does
                with the high encoding bands.
            view_dependent: colour depends on the view direction (False: the views augmentation).
            view_bands: bands of the direction encoding gamma(v, 0, L_v) fed to the colour MLP (shared with the other
                fields through the samples' cache).
            hidden: width of the density and colour MLPs (one hidden layer each).
            geometry_features: features passed from the density MLP to the colour MLP.
            tv_weight: initial weight of the planes' total variation (K-Planes' spatial TV; 0: off), the objective's
                term `tv_<field>` (`regularizers`; a `LossWeightSchedule` may set it).
            depth_tv_scale: the TV of the xz and yz planes counts this many times the xy planes' in the term.
            init_range: planes are initialised uniformly in this range (K-Planes: (0.1, 0.5)).
            density_shift: added to the density MLP's output before the exponential (DVGO's "act_shift"): negative
                values start training from nearly empty space instead of a fog in front of the cameras.
            extent: (e_x, e_y), the planes' half-widths along NDC x and y: node 0 sits at -e, node n - 1 at +e (z
                always spans [-1, 1]). (1, 1): the reference camera's image only, and what other cameras see past
                its edges takes the planes' border values. TensoRF's box for LLFF in NDC (its `dataLoader/llff.py`,
                `scene_bbox`) is (1.5, 1.67) (docs/results.md, "Where the blur and the streaks come from", 36).
        """
        super().__init__()
        resolutions = [64, 128, 256] if resolutions is None else list(resolutions)
        depth_resolutions = resolutions if depth_resolutions is None else list(depth_resolutions)
        if not resolutions or len(depth_resolutions) != len(resolutions):
            raise ValueError(f"need one depth resolution per scale, got {resolutions} and {depth_resolutions}")
        if min(resolutions + depth_resolutions) < 2:
            raise ValueError(f"every axis needs at least 2 nodes, got {resolutions} and {depth_resolutions}")
        density_scales = len(resolutions) if density_scales is None else density_scales
        if not 0 < density_scales <= len(resolutions):
            raise ValueError(f"density_scales must be in [1, {len(resolutions)}], got {density_scales}")
        density_features = features if density_features is None else density_features
        if not 0 < density_features <= features:
            raise ValueError(f"density_features must be in [1, {features}], got {density_features}")
        unseen = features * len(resolutions) - density_features * density_scales  # channels the density MLP skips
        if unseen and not residual_scales_to_color:
            raise ValueError("features beyond density_scales / density_features would be unused; set "
                             "residual_scales_to_color or drop them")
        self.resolutions, self.depth_resolutions = resolutions, depth_resolutions
        self.density_scales, self.residual_scales_to_color = density_scales, residual_scales_to_color
        self.density_features = density_features
        self.features, self.view_dependent, self.view_bands = features, view_dependent, view_bands
        self.tv_weight, self.depth_tv_scale, self.density_shift = tv_weight, depth_tv_scale, density_shift
        extent = tuple(float(e) for e in extent)
        if len(extent) != 2 or not min(extent) > 0:
            raise ValueError(f"extent must be two positive half-widths (x, y), got {extent}")
        self.extent = extent
        self.planes = nn.ParameterList()
        for res, res_z in zip(resolutions, depth_resolutions, strict=True):
            nodes = (res, res, res_z)
            for width_axis, height_axis in PLANE_AXES:
                plane = torch.empty(1, features, nodes[height_axis], nodes[width_axis]).uniform_(*init_range)
                self.planes.append(nn.Parameter(plane))
        self.density_net = nn.Sequential(
            nn.Linear(density_features * density_scales, hidden), nn.ReLU(), nn.Linear(hidden, 1 + geometry_features)
        )
        color_in = geometry_features + unseen + (encoded_dim(3, view_bands) if view_dependent else 0)
        self.color_net = nn.Sequential(nn.Linear(color_in, hidden), nn.ReLU(), nn.Linear(hidden, 3))

    def grid_features(self, positions: torch.Tensor) -> torch.Tensor:
        """The multi-scale plane features of points.

        Args:
            positions: [P, 3] NDC points.

        Returns:
            [P, C * scales]: per scale, the product of the three planes' interpolations; scales concatenated.
        """
        if self.extent != (1.0, 1.0):  # plane coordinates: [-extent, extent] -> [-1, 1]
            positions = positions * positions.new_tensor((1.0 / self.extent[0], 1.0 / self.extent[1], 1.0))
        coords = [positions[:, list(axes)] for axes in PLANE_AXES]  # shared by every scale
        per_scale = []
        for scale in range(len(self.resolutions)):
            planes = self.planes[3 * scale : 3 * scale + 3]
            feature = sample_plane(planes[0], coords[0])
            for plane, plane_coords in zip(planes[1:], coords[1:], strict=True):
                feature = feature * sample_plane(plane, plane_coords)
            per_scale.append(feature)
        return torch.cat(per_scale, dim=0).t()

    def split_features(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """[P, C scales] grid features -> (what the density MLP sees [P, density_features density_scales], the rest
        [P, C scales - that], scale-major in both)."""
        points, scales = features.shape[0], len(self.resolutions)
        if self.density_features == self.features:  # whole scales: a leading slice
            split = self.features * self.density_scales
            return features[:, :split], features[:, split:]
        per_scale = features.reshape(points, scales, self.features)
        seen = per_scale[:, : self.density_scales, : self.density_features].reshape(points, -1)
        rest = [per_scale[:, : self.density_scales, self.density_features :].reshape(points, -1),
                per_scale[:, self.density_scales :].reshape(points, -1)]
        return seen, torch.cat(rest, dim=-1)

    def forward(self, samples: Samples) -> FieldOutputs:
        """Density and colour at the samples' NDC positions (and view directions if `view_dependent`)."""
        rays, num = samples.positions.shape[:2]
        features = self.grid_features(samples.positions.reshape(-1, 3))  # [R S, C scales]
        seen, rest = self.split_features(features)
        h = self.density_net(seen)  # [R S, 1 + G]
        raw_density = trunc_exp(h[:, 0] + self.density_shift).view(rays, num)
        if not samples.color:  # density only (no loss reads the colour at these samples)
            return FieldOutputs(raw_density=raw_density, rgb=None)
        color_in = [h[:, 1:]]
        if self.residual_scales_to_color:
            color_in.append(rest)
        if self.view_dependent:
            dirs = samples.encoded_directions(self.view_bands)  # [R, D]
            color_in.append(dirs[:, None, :].expand(rays, num, dirs.shape[-1]).reshape(rays * num, -1).to(h.dtype))
        rgb = torch.sigmoid(self.color_net(torch.cat(color_in, dim=-1)))
        return FieldOutputs(raw_density=raw_density, rgb=rgb.view(rays, num, 3))

    def parameter_groups(self) -> dict[str, list[nn.Parameter]]:
        """{"grid": the planes, "decoder": the MLPs}: grids train with a much larger learning rate than MLPs."""
        return {"grid": list(self.planes), "decoder": [*self.density_net.parameters(), *self.color_net.parameters()]}

    def regularizers(self) -> dict[str, float]:
        """{"tv": tv_weight}: the planes' total variation, a term of the objective."""
        return {"tv": self.tv_weight}

    def regularization(self, name: str) -> torch.Tensor:
        """"tv": sum of the xy planes' TV + depth_tv_scale * sum of the xz and yz planes' TV (K-Planes), unweighted."""
        if name != "tv":
            return super().regularization(name)
        xy = sum(plane_tv(plane) for plane in self.planes[0::3])
        depth = sum(plane_tv(plane) for i, plane in enumerate(self.planes) if i % 3)
        return xy + self.depth_tv_scale * depth

    def extra_repr(self) -> str:
        return (f"resolutions={self.resolutions}, depth_resolutions={self.depth_resolutions}, "
                f"features={self.features}, density_features={self.density_features}, "
                f"view_dependent={self.view_dependent}, extent={self.extent}")
