import math

import torch

from simplenerf.geometry.rays import make_rays, ndc_rays, ndc_to_metric_t, pixel_rays, project

K = torch.tensor([[[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]]])


def rotation_y(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def camera(angle: float = 0.1, centre=(0.2, -0.1, 0.3)) -> torch.Tensor:
    return torch.cat([rotation_y(angle), torch.tensor(centre)[:, None]], dim=1)[None]


def test_principal_pixel_looks_down_minus_z_with_unit_z():
    o, d = pixel_rays(K, camera(0.0, (0.0, 0.0, 0.0)), torch.tensor([[32, 24], [42, 24], [32, 14]]))
    assert torch.allclose(d[0], torch.tensor([0.0, 0.0, -1.0]))
    assert torch.allclose(d[1], torch.tensor([0.2, 0.0, -1.0]))  # right of centre -> +x
    assert torch.allclose(d[2], torch.tensor([0.0, 0.2, -1.0]))  # above centre (smaller row) -> +y
    assert torch.equal(o, torch.zeros(3, 3))


def test_project_inverts_pixel_rays_and_t_is_camera_depth():
    c2w = camera()
    uv = torch.tensor([[3.0, 7.0], [60.0, 40.0], [32.0, 24.0]])
    o, d = pixel_rays(K, c2w, uv)
    depth = torch.tensor([1.5, 4.0, 10.0])
    uv_back, z = project(o + depth[:, None] * d, K, c2w)
    assert torch.allclose(uv_back, uv, atol=1e-4)
    assert torch.allclose(z, depth, atol=1e-5)


def test_ndc_round_trip_maps_samples_back_to_metric_depth():
    c2w = camera(0.05, (0.1, 0.05, 0.2))
    uv = torch.tensor([[0.0, 0.0], [63.0, 47.0], [20.0, 30.0]])
    rays = make_rays(K, c2w, uv, width=64, height=48, near=1.0)
    t_ndc = torch.tensor([[0.0, 0.3, 0.6, 0.95]]).expand(3, 4)
    t_metric = ndc_to_metric_t(t_ndc, rays, near=1.0)
    world = rays.origins[:, None] + t_metric[..., None] * rays.directions[:, None]
    # The NDC image of those world points is the NDC ray at the same t.
    ndc_point = rays.ndc_origins[:, None] + t_ndc[..., None] * rays.ndc_directions[:, None]
    ax, ay = -2 * 50.0 / 64, -2 * 50.0 / 48
    expected = torch.stack(
        [ax * world[..., 0] / world[..., 2], ay * world[..., 1] / world[..., 2], 1 + 2 / world[..., 2]], dim=-1
    )
    assert torch.allclose(ndc_point, expected, atol=1e-4)
    # NDC t = 0 is the near plane z = -1.
    assert torch.allclose(world[:, 0, 2], torch.full((3,), -1.0), atol=1e-5)
    assert bool((t_metric[:, 1:] > t_metric[:, :-1]).all())


def test_ndc_t_one_is_finite():
    rays = make_rays(K, camera(), torch.tensor([[5.0, 5.0]]), 64, 48, 1.0)
    t = ndc_to_metric_t(torch.tensor([[1.0]]), rays, near=1.0)
    assert torch.isfinite(t).all() and t.item() > 1e4


def test_ndc_of_axis_ray():
    o = torch.tensor([[0.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, -1.0]])
    ndc_o, ndc_d = ndc_rays(o, d, K, 64, 48, near=1.0)
    assert torch.allclose(ndc_o, torch.tensor([[0.0, 0.0, -1.0]]))
    assert torch.allclose(ndc_d, torch.tensor([[0.0, 0.0, 2.0]]))


def test_pixel_grid_is_row_major_column_row():
    from simplenerf.geometry.rays import pixel_grid

    assert pixel_grid(2, 3).tolist() == [[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]]


def test_kornia_geometry_matches_the_explicit_pinhole_formulas():
    """pixel_rays / project go through kornia; the explicit formulas of the module docstring give the same."""
    g = torch.Generator().manual_seed(0)
    n = 200
    intrinsics = torch.tensor([[500.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]]).repeat(n, 1, 1)
    intrinsics[:, 0, 0] += 10 * torch.rand(n, generator=g)
    rotation, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=g))
    c2w = torch.cat([rotation, torch.randn(n, 3, 1, generator=g)], dim=-1)
    uv = 600 * torch.rand(n, 2, generator=g)
    fx, fy, cx, cy = intrinsics[:, 0, 0], intrinsics[:, 1, 1], intrinsics[:, 0, 2], intrinsics[:, 1, 2]
    d_cam = torch.stack([(uv[:, 0] - cx) / fx, -(uv[:, 1] - cy) / fy, -torch.ones(n)], dim=-1)
    origins, directions = pixel_rays(intrinsics, c2w, uv)
    assert torch.equal(directions, (rotation @ d_cam[..., None])[..., 0]) and torch.equal(origins, c2w[:, :, 3])
    points = origins + 3.0 * directions  # camera z-depth 3 by the direction convention
    p_cam = ((points - c2w[:, :, 3])[:, None, :] @ rotation)[:, 0, :]
    explicit = torch.stack([fx * p_cam[:, 0] / -p_cam[:, 2] + cx, -fy * p_cam[:, 1] / -p_cam[:, 2] + cy], dim=-1)
    uv_back, z = project(points, intrinsics, c2w)
    assert torch.allclose(uv_back, explicit, atol=1e-3) and torch.allclose(uv_back, uv, atol=1e-3)
    assert torch.allclose(z, torch.full((n,), 3.0), atol=1e-4)
