"""Cameras, pixel rays and normalised device coordinates (NDC).

Conventions, used by every module of the package:
- Cameras: `intrinsics` [..., 3, 3] with fx, fy, cx, cy; `c2w` [..., 3, 4] camera-to-world in OpenGL axes (columns:
  camera right, up, back; the camera looks along -z).
- Pixel (u, v) (u = column, v = row) is the ray through the integer image coordinate (u, v), no +0.5, with
  camera-frame direction [(u - cx) / fx, -(v - cy) / fy, -1]. Directions are NOT normalised, so the distance t along
  a ray (point = o + t d) is the camera z-depth of the point: "metric t" and "depth" are the same number.
- NDC is the standard forward-facing (LLFF) one with the near plane at `near` (1 after the scene scaling). Samples
  are placed uniformly in NDC t in [0, 1], which is uniform in disparity; `ndc_to_metric_t` maps them back.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from kornia.geometry.camera.perspective import project_points, unproject_points


@dataclass
class RayBundle:
    """A batch of rays in both parametrisations. All tensors [R, 3].

    origins, directions: world-space rays (directions un-normalised, see the module docstring).
    ndc_origins, ndc_directions: the same rays in NDC, where samples are drawn.
    """

    origins: torch.Tensor
    directions: torch.Tensor
    ndc_origins: torch.Tensor
    ndc_directions: torch.Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index: slice | torch.Tensor) -> RayBundle:
        return RayBundle(*(getattr(self, f.name)[index] for f in fields(self)))

    def to(self, device: torch.device | str) -> RayBundle:
        """The same rays on `device`."""
        return RayBundle(*(getattr(self, f.name).to(device) for f in fields(self)))

    def cat(self, other: RayBundle) -> RayBundle:
        """These rays followed by `other`'s."""
        return RayBundle(*(torch.cat([getattr(self, f.name), getattr(other, f.name)]) for f in fields(self)))


def pixel_grid(height: int, width: int, device: torch.device | str | None = None) -> torch.Tensor:
    """Every pixel (u, v) of an image, row-major (v outer, u inner): [height * width, 2] long, (column, row)."""
    v, u = torch.meshgrid(torch.arange(height, device=device), torch.arange(width, device=device), indexing="ij")
    return torch.stack([u.flatten(), v.flatten()], dim=-1)


# Our camera axes (OpenGL: right, up, back) -> kornia's / OpenCV's (right, down, forward), and back: flip y and z.
_GL_CV_FLIP = (1.0, -1.0, -1.0)


def pixel_rays(intrinsics: torch.Tensor, c2w: torch.Tensor, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World rays through pixels (kornia's unprojection at unit OpenCV depth, turned into OpenGL axes).

    Args:
        intrinsics: [R, 3, 3] (or broadcastable, e.g. [1, 3, 3]).
        c2w: [R, 3, 4] (or broadcastable).
        uv: [R, 2] pixel coordinates (column, row), integer-valued for pixel centres of this convention.

    Returns:
        origins [R, 3], directions [R, 3] (un-normalised, camera-frame z = -1).
    """
    uv = uv.to(c2w.dtype)
    d_cv = unproject_points(uv, torch.ones_like(uv[..., :1]), intrinsics)  # [(u - cx) / fx, (v - cy) / fy, 1]
    d_cam = d_cv * d_cv.new_tensor(_GL_CV_FLIP)  # [(u - cx) / fx, -(v - cy) / fy, -1]
    directions = (c2w[..., :3, :3] @ d_cam[..., None])[..., 0]
    origins = c2w[..., :3, 3].expand_as(directions)
    return origins, directions


def project(points: torch.Tensor, intrinsics: torch.Tensor, c2w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Projects world points into a camera (inverse of `pixel_rays`; the pinhole step is kornia's).

    Args:
        points: [R, 3] world points. intrinsics [R or 1, 3, 3], c2w [R or 1, 3, 4].

    Returns:
        uv [R, 2] continuous pixel coordinates in this module's convention, z [R] camera z-depth (positive in front).
    """
    rotation, centre = c2w[..., :3, :3], c2w[..., :3, 3]
    p_cam = ((points - centre)[..., None, :] @ rotation)[..., 0, :]  # R^T (p - c), as row vectors
    p_cv = p_cam * p_cam.new_tensor(_GL_CV_FLIP)  # OpenCV camera frame: z = camera z-depth
    return project_points(p_cv, intrinsics), p_cv[..., 2]


def ndc_rays(
    origins: torch.Tensor, directions: torch.Tensor, intrinsics: torch.Tensor, width: int, height: int, near: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward-facing NDC rays (Mildenhall et al. 2020, App. C), per-view focal lengths.

    The origin is first moved to the near plane z = -near. Assumes the principal point is the image centre,
    as in LLFF and RealEstate-10K.

    Args:
        origins, directions: [R, 3] world rays. intrinsics: [R or 1, 3, 3].

    Returns:
        ndc_origins [R, 3], ndc_directions [R, 3]: NDC t = 0 is the near plane, t = 1 is infinity.
    """
    t_near = -(near + origins[..., 2]) / directions[..., 2]
    o = origins + t_near[..., None] * directions
    ax = -2.0 * intrinsics[..., 0, 0] / width
    ay = -2.0 * intrinsics[..., 1, 1] / height
    ox_oz, oy_oz = o[..., 0] / o[..., 2], o[..., 1] / o[..., 2]
    ndc_o = torch.stack([ax * ox_oz, ay * oy_oz, 1.0 + 2.0 * near / o[..., 2]], dim=-1)
    ndc_d = torch.stack(
        [
            ax * (directions[..., 0] / directions[..., 2] - ox_oz),
            ay * (directions[..., 1] / directions[..., 2] - oy_oz),
            -2.0 * near / o[..., 2],
        ],
        dim=-1,
    )
    return ndc_o, ndc_d


def ndc_to_metric_t(t_ndc: torch.Tensor, rays: RayBundle, near: float, eps: float = 1e-6) -> torch.Tensor:
    """Maps NDC sample positions to metric t along the world ray (= camera z-depth).

    NDC z is 1 + 2 near / Z for world z = Z, so Z = 2 near / (z_ndc - 1); then t = (Z - o_z) / d_z on the original
    world ray. NDC t = 1 (z_ndc = 1) is infinitely far; it is clamped to a large finite depth so that a zero weight
    times that depth stays zero.

    Args:
        t_ndc: [R, S] sample positions in [0, 1].

    Returns:
        [R, S] metric t.
    """
    z_ndc = rays.ndc_origins[:, None, 2] + t_ndc * rays.ndc_directions[:, None, 2]
    world_z = 2.0 * near / torch.clamp(z_ndc - 1.0, max=-eps)
    return (world_z - rays.origins[:, None, 2]) / rays.directions[:, None, 2]


def make_rays(
    intrinsics: torch.Tensor, c2w: torch.Tensor, uv: torch.Tensor, width: int, height: int, near: float
) -> RayBundle:
    """Rays through pixels uv [R, 2] of cameras intrinsics [R or 1, 3, 3], c2w [R or 1, 3, 4], in both
    parametrisations."""
    origins, directions = pixel_rays(intrinsics, c2w, uv)
    ndc_o, ndc_d = ndc_rays(origins, directions, intrinsics, width, height, near)
    return RayBundle(origins, directions, ndc_o, ndc_d)
