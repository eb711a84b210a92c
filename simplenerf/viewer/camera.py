"""The browser's camera as this package's camera, and back.

viser reports a client's camera as a rotation `wxyz` (a quaternion, camera to world) and a `position`, in OpenCV axes
(x right, y down, z forward), with a vertical field of view `fov` (radians) and the canvas' `aspect` (width / height).
This package's cameras are c2w [3, 4] in OpenGL axes (right, up, back; `simplenerf.geometry.rays`): the same matrix
with its y and z columns negated. A render of W x H pixels has square pixels, fy = fx = (H / 2) / tan(fov / 2) and
the principal point at the image centre (W / 2, H / 2), the convention of the data (pixel (u, v) without +0.5).

The NeRF samples in forward-facing NDC (LLFF), defined by the train views' camera: the viewer's rays are put in that
NDC whatever the viewer's own field of view and size. A ray that does not point into the scene (world direction with
d_z >= 0) has no NDC parametrisation, so it is marked invalid and drawn as background.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import viser.transforms as vtf

from simplenerf.geometry.rays import RayBundle, ndc_rays, pixel_grid, pixel_rays

_FLIP_YZ = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes <-> OpenGL camera axes


@dataclass(frozen=True)
class ViewerCamera:
    """A camera the viewer renders from."""

    c2w: np.ndarray  # [3, 4] camera-to-world, OpenGL axes, scene units
    fov_y: float  # vertical field of view, radians
    aspect: float  # width / height

    def __post_init__(self) -> None:
        if np.shape(self.c2w) != (3, 4):
            raise ValueError(f"c2w must be [3, 4], got {np.shape(self.c2w)}")
        if not 0.0 < self.fov_y < math.pi or not self.aspect > 0.0:
            raise ValueError(f"fov_y must be in (0, pi) and aspect positive, got {self.fov_y}, {self.aspect}")

    def image_size(self, max_side: int) -> tuple[int, int]:
        """(width, height) of a render whose larger side is `max_side` pixels, at this camera's aspect (>= 1 each)."""
        if self.aspect >= 1.0:
            return max_side, max(1, round(max_side / self.aspect))
        return max(1, round(max_side * self.aspect)), max_side

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        """[3, 3] pinhole intrinsics of a width x height render (square pixels, centred principal point)."""
        focal = 0.5 * height / math.tan(0.5 * self.fov_y)
        return np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])

    @property
    def centre(self) -> np.ndarray:
        """[3] camera centre in world coordinates."""
        return self.c2w[:, 3]


def camera_from_viser(wxyz: np.ndarray, position: np.ndarray, fov: float, aspect: float) -> ViewerCamera:
    """The client's camera (viser's OpenCV pose, vertical fov in radians, aspect) as a `ViewerCamera`."""
    rotation_cv = vtf.SO3(np.asarray(wxyz, dtype=np.float64)).as_matrix()
    c2w = np.concatenate([rotation_cv @ _FLIP_YZ, np.asarray(position, dtype=np.float64).reshape(3, 1)], axis=1)
    return ViewerCamera(c2w=c2w, fov_y=float(fov), aspect=float(aspect))


def viser_pose(c2w: np.ndarray | torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz [4], position [3]) of viser's OpenCV pose for a c2w [3, 4] in OpenGL axes (inverse of
    `camera_from_viser`): how a frustum or the browser's camera is placed at one of our cameras."""
    c2w = c2w.detach().cpu().double().numpy() if isinstance(c2w, torch.Tensor) else np.asarray(c2w, np.float64)
    return vtf.SO3.from_matrix(c2w[:, :3] @ _FLIP_YZ).wxyz, c2w[:, 3].copy()


def vertical_fov(intrinsics: np.ndarray | torch.Tensor, height: int) -> float:
    """The vertical field of view (radians) of a camera with intrinsics [3, 3] and `height` pixels."""
    return 2.0 * math.atan(0.5 * height / float(intrinsics[1, 1]))


def look_at_point(c2w: np.ndarray, distance: float) -> np.ndarray:
    """[3] the point `distance` scene units in front of a camera c2w [3, 4] (OpenGL: it looks along -z)."""
    return c2w[:, 3] - distance * c2w[:, 2]


def viewer_rays(
    camera: ViewerCamera, width: int, height: int, near: float, ndc: tuple[torch.Tensor, int, int], like: torch.Tensor
) -> tuple[RayBundle, torch.Tensor]:
    """Rays of every pixel of a width x height render from `camera`, row-major, in the dtype and on the device of
    `like` (a model parameter).

    The NDC the model samples in is the data's, fixed by the train views' camera: `ndc` = (intrinsics [3, 3], width,
    height) of a train view. Built with the viewer's own camera instead it would be another space (NDC x and y scale
    with fx / W and fy / H), and the render a stretched, zoomed scene.

    Returns:
        rays [H * W] (world and NDC), valid [H * W] bool: the rays that point into the scene (d_z < 0), which alone
        have an NDC parametrisation; the others' NDC values are not finite and must not be rendered.
    """
    c2w = torch.as_tensor(camera.c2w, dtype=like.dtype, device=like.device)
    intrinsics = torch.as_tensor(camera.intrinsics(width, height), dtype=like.dtype, device=like.device)
    origins, directions = pixel_rays(intrinsics[None], c2w[None], pixel_grid(height, width, like.device))
    ndc_intrinsics, ndc_width, ndc_height = ndc
    ndc_o, ndc_d = ndc_rays(origins, directions, ndc_intrinsics.to(like.device, like.dtype)[None], ndc_width,
                            ndc_height, near)
    valid = directions[:, 2] < -1e-6
    return RayBundle(origins, directions, ndc_o, ndc_d), valid


def nearest_camera(camera: ViewerCamera, c2w: torch.Tensor) -> int:
    """Index of the camera among c2w [V, 3, 4] whose centre is closest to `camera`'s (ties: the lowest index), the
    rule `Views.nearest` uses between train views."""
    centres = c2w[:, :3, 3].detach().cpu().double()
    distance = (centres - torch.from_numpy(camera.centre)).square().sum(-1)
    return int(distance.argmin())
