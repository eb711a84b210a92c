import math

import numpy as np
import pytest
import torch
import viser.transforms as vtf

from simplenerf.data.llff import load_llff_scene
from simplenerf.geometry.rays import pixel_grid
from simplenerf.viewer.camera import (
    ViewerCamera,
    camera_from_viser,
    nearest_camera,
    vertical_fov,
    viewer_rays,
    viser_pose,
)


def test_image_size_and_intrinsics():
    camera = ViewerCamera(np.eye(3, 4), fov_y=math.radians(90.0), aspect=4 / 3)
    assert camera.image_size(128) == (128, 96)
    assert ViewerCamera(np.eye(3, 4), 1.0, 0.5).image_size(128) == (64, 128)
    # tan(45 deg) = 1: focal = half the height; principal point at the centre
    assert np.allclose(camera.intrinsics(128, 96), [[48.0, 0.0, 64.0], [0.0, 48.0, 48.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="fov_y"):
        ViewerCamera(np.eye(3, 4), fov_y=4.0, aspect=1.0)


def test_viser_identity_camera_looks_along_world_plus_z():
    # viser's cameras are OpenCV (x right, y down, z forward): ours (OpenGL) then look along -(-z) = +z.
    camera = camera_from_viser(np.array([1.0, 0.0, 0.0, 0.0]), np.array([1.0, 2.0, 3.0]), 1.0, 1.5)
    assert np.allclose(camera.c2w, [[1, 0, 0, 1], [0, -1, 0, 2], [0, 0, -1, 3]])


def test_viser_pose_round_trip():
    rotation = vtf.SO3.from_rpy_radians(0.3, -0.7, 1.1).as_matrix()
    c2w = np.concatenate([rotation, [[0.5], [-1.0], [2.0]]], axis=1)
    wxyz, position = viser_pose(torch.from_numpy(c2w))
    back = camera_from_viser(wxyz, position, 0.8, 1.0)
    assert np.allclose(back.c2w, c2w, atol=1e-12)


def test_a_camera_at_a_train_view_gives_that_views_rays(synthetic_scene):
    views = load_llff_scene(synthetic_scene, factor=1, n_views=2).views
    k = views.intrinsics[3]
    camera = ViewerCamera(views.c2w[3].double().numpy(), vertical_fov(k, views.height), views.width / views.height)
    ndc = (views.intrinsics[0], views.width, views.height)
    rays, valid = viewer_rays(camera, views.width, views.height, 1.0, ndc, like=views.c2w)
    uv = pixel_grid(views.height, views.width)
    expected = views.rays(torch.full((len(uv),), 3), uv, 1.0)
    assert len(rays) == views.height * views.width and bool(valid.all())
    for name in ("origins", "directions", "ndc_origins", "ndc_directions"):
        assert torch.allclose(getattr(rays, name), getattr(expected, name), atol=1e-5), name


def test_rays_that_point_away_from_the_scene_are_invalid():
    turned = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])  # OpenGL: looks along -z, into the scene
    ndc = (torch.tensor([[4.0, 0, 2], [0, 4, 2], [0, 0, 1]]), 4, 4)
    assert bool(viewer_rays(ViewerCamera(turned, 1.0, 1.0), 4, 4, 1.0, ndc, torch.zeros(1))[1].all())
    backwards = turned * [[-1], [1], [-1]]  # rotated 180 degrees about y: looks along +z
    assert not bool(viewer_rays(ViewerCamera(backwards, 1.0, 1.0), 4, 4, 1.0, ndc, torch.zeros(1))[1].any())


def test_the_ndc_is_the_datas_whatever_the_viewers_camera(synthetic_scene):
    # The same world ray has the same NDC ray whether it comes from a train view or from a wider, larger viewer
    # camera at the same pose: the centre pixel of both looks along the camera's axis.
    views = load_llff_scene(synthetic_scene, factor=1, n_views=2).views
    ndc = (views.intrinsics[0], views.width, views.height)
    wide = ViewerCamera(views.c2w[0].double().numpy(), fov_y=1.2, aspect=2.0)
    rays, _ = viewer_rays(wide, 200, 100, 1.0, ndc, like=views.c2w)
    centre = 50 * 200 + 100  # pixel (100, 50) = the principal point (W / 2, H / 2)
    uv = torch.tensor([[views.width // 2, views.height // 2]])  # the train view's principal point
    expected = views.rays(torch.zeros(1, dtype=torch.long), uv, 1.0)
    assert torch.allclose(rays.ndc_origins[centre], expected.ndc_origins[0], atol=1e-5)
    assert torch.allclose(rays.ndc_directions[centre] / rays.ndc_directions[centre].norm(),
                          expected.ndc_directions[0] / expected.ndc_directions[0].norm(), atol=1e-5)


def test_nearest_camera_by_centre():
    c2w = torch.zeros(3, 3, 4)
    c2w[:, :, 3] = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    camera = ViewerCamera(np.concatenate([np.eye(3), [[1.4], [0.3], [0.0]]], axis=1), 1.0, 1.0)
    assert nearest_camera(camera, c2w) == 1
