"""The viewer's 3D scene: each train and test camera as a frustum with its photo, and the SfM points that serve as
sparse depth (DS-NeRF's prior, `simplenerf.sfm.sparse_depth`), in the scene's units and axes (+y up)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from simplenerf.data.datasets import SparseDepthPool
from simplenerf.geometry.views import Views
from simplenerf.viewer.camera import vertical_fov, viser_pose
from simplenerf.viz.pictures import to_uint8

TRAIN_COLOUR, TEST_COLOUR = (255, 140, 0), (40, 120, 255)  # orange train views, blue test frames


@dataclass
class ScenePoints:
    """SfM points: positions [P, 3] (scene units) and 8-bit colours [P, 3] from the photo that observed them."""

    positions: np.ndarray
    colours: np.ndarray


def sfm_points(pool: SparseDepthPool, train: Views) -> ScenePoints:
    """The world points of the sparse-depth observations: pixel uv of train view `view` at camera z-depth `depth`
    (point = o + depth d, directions with camera z = -1), coloured by that view's photo at the nearest pixel."""
    view = pool.view.long()
    origins, directions = train.pixel_rays(view, pool.uv.to(train.c2w.dtype))
    positions = origins + pool.depth.to(train.c2w.dtype)[:, None] * directions
    u = pool.uv[:, 0].round().long().clamp(0, train.width - 1)
    v = pool.uv[:, 1].round().long().clamp(0, train.height - 1)
    colours = to_uint8(train.images[view, v, u].float().cpu().numpy())
    return ScenePoints(positions.float().cpu().numpy(), colours)


def thumbnail(image: torch.Tensor, max_side: int = 256) -> np.ndarray:
    """An 8-bit copy of a photo [H, W, 3] in [0, 1] whose larger side is at most `max_side` pixels."""
    picture = to_uint8(image.float().cpu().numpy())
    h, w = picture.shape[:2]
    if max(h, w) <= max_side:
        return picture
    scale = max_side / max(h, w)
    return cv2.resize(picture, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def add_cameras(server, views: Views, indices: list[int], role: str, colour: tuple[int, int, int],
                scale: float) -> list:
    """A frustum per view `indices` of `views` (all frames of the scene) named /cameras/<role>/<frame name>, with
    its photo. Returns the handles."""
    handles = []
    fov = vertical_fov(views.intrinsics[0], views.height)
    for i in indices:
        wxyz, position = viser_pose(views.c2w[i])
        handles.append(server.scene.add_camera_frustum(
            f"/cameras/{role}/{views.names[i]}", fov=fov, aspect=views.width / views.height, scale=scale,
            thickness=2.0, thickness_units="screen", color=colour, image=thumbnail(views.images[i]), wxyz=wxyz,
            position=position,
        ))
    return handles


def add_points(server, points: ScenePoints, size: float) -> None:
    """The SfM points as a point cloud named /sparse_depth."""
    if len(points.positions):
        server.scene.add_point_cloud("/sparse_depth", points=points.positions, colors=points.colours,
                                     point_size=size, point_shape="circle")


def frustum_scale(bounds: np.ndarray) -> float:
    """Frustum size (scene units) for a scene with near/far bounds [N, 2]: a twentieth of the nearest depth, so the
    frustums stay well in front of the content."""
    return 0.05 * float(np.min(bounds[:, 0]))
