import math

import numpy as np
import pytest
import torch

from simplenerf.data.llff import load_llff_scene, subset
from simplenerf.data.scene import Scene, Split
from simplenerf.geometry.poses import average_pose
from simplenerf.geometry.trajectories import llff_spiral, recorded_trajectory, spiral_focus_depth
from simplenerf.geometry.views import Views

# Four axis-aligned cameras (identity rotation) around the origin: the average pose is the identity.
POSITIONS = torch.tensor([[-0.2, 0.1, 0.02], [0.2, -0.1, -0.02], [0.1, 0.05, 0.04], [-0.1, -0.05, -0.04]],
                         dtype=torch.float64)
BOUNDS = np.array([[1.0, 10.0], [2.0, 20.0], [1.5, 12.0], [1.2, 15.0]])
FOCUS = 1.0 / (0.25 / 0.9 + 0.75 / 100.0)  # close = 0.9 * 1.0, inf = 5 * 20


def axis_aligned_rig() -> torch.Tensor:
    return torch.cat([torch.eye(3, dtype=torch.float64).expand(4, 3, 3), POSITIONS[:, :, None]], dim=-1)


def rotation(axis: list[float], angle: float) -> torch.Tensor:
    """Rodrigues' rotation matrix, float64."""
    k = torch.tensor(axis, dtype=torch.float64)
    k = k / k.norm()
    cross = torch.tensor([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


def test_focus_depth_is_the_llff_weighted_harmonic_mean():
    assert spiral_focus_depth(BOUNDS) == pytest.approx(FOCUS, rel=1e-12)
    assert FOCUS == pytest.approx(3.50535, rel=1e-5)


def test_spiral_positions_follow_the_formula():
    c2w = llff_spiral(axis_aligned_rig(), BOUNDS)
    assert c2w.shape == (120, 3, 4) and c2w.dtype == torch.float64
    radii = [0.2, 0.1, 0.04]  # 90th percentiles of |x|, |y|, |z| (the centre is the origin): the larger of each pair
    # frame 0: theta = 0; frame 15: theta = 15 * 4 pi / 120 = pi / 2 (zrate 0.5: sin(pi / 4))
    assert torch.allclose(c2w[0, :, 3], torch.tensor([radii[0], 0.0, 0.0], dtype=torch.float64), atol=1e-12)
    expected = torch.tensor([0.0, -radii[1], -radii[2] * math.sin(math.pi / 4)], dtype=torch.float64)
    assert torch.allclose(c2w[15, :, 3], expected, atol=1e-12)
    # two full turns: the path is centred on the average train pose
    assert torch.allclose(c2w[:, :, 3].mean(0), torch.zeros(3, dtype=torch.float64), atol=1e-12)


def test_spiral_makes_two_rotations():
    x = llff_spiral(axis_aligned_rig(), BOUNDS, n_frames=120, n_rotations=2)[:, 0, 3]
    signs = torch.sign(x[torch.abs(x) > 1e-9])
    assert int((signs[1:] != signs[:-1]).sum()) == 4  # x = r cos(theta), theta in [0, 4 pi): crosses 0 four times
    assert len(llff_spiral(axis_aligned_rig(), BOUNDS, n_frames=7)) == 7


def test_spiral_poses_are_rotations_looking_at_the_focus_point():
    c2w = llff_spiral(axis_aligned_rig(), BOUNDS)
    rot = c2w[:, :, :3]
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3, dtype=torch.float64).expand(120, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(120, dtype=torch.float64), atol=1e-12)
    focus = torch.tensor([0.0, 0.0, -FOCUS], dtype=torch.float64)
    to_focus = focus - c2w[:, :, 3]
    assert torch.allclose(to_focus / to_focus.norm(dim=-1, keepdim=True), -rot[:, :, 2], atol=1e-12)
    # roughly along the rig's viewing direction -z, with the rig's up
    assert rot[:, 2, 2].min() > 0.99 and rot[:, 1, 1].min() > 0.99  # back axis ~ +z, i.e. looking along -z


def test_spiral_turns_with_the_rig():
    """Rotating and moving all train cameras rotates and moves the path the same way."""
    r, t = rotation([0.3, 1.0, -0.2], 0.7), torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    rig = axis_aligned_rig()
    moved = torch.cat([r @ rig[:, :, :3], (r @ rig[:, :, 3:]) + t[:, None]], dim=-1)
    base, turned = llff_spiral(rig, BOUNDS), llff_spiral(moved, BOUNDS)
    assert torch.allclose(turned[:, :, :3], r @ base[:, :, :3], atol=1e-10)
    assert torch.allclose(turned[:, :, 3], base[:, :, 3] @ r.T + t, atol=1e-10)


def test_spiral_keeps_dtype_and_checks_inputs():
    assert llff_spiral(axis_aligned_rig().float(), torch.from_numpy(BOUNDS)).dtype == torch.float32
    with pytest.raises(ValueError, match="c2w must be"):
        llff_spiral(axis_aligned_rig()[:, :, :3], BOUNDS)
    with pytest.raises(ValueError, match="bounds must be"):
        llff_spiral(axis_aligned_rig(), BOUNDS[:2])
    with pytest.raises(ValueError, match="n_frames"):
        llff_spiral(axis_aligned_rig(), BOUNDS, n_frames=0)


def test_recorded_trajectory_is_the_frames_in_order():
    c2w = axis_aligned_rig().float()
    views = Views(images=torch.zeros(4, 2, 2, 3), intrinsics=torch.eye(3).expand(4, 3, 3), c2w=c2w,
                  names=["a", "b", "c", "d"])
    path = recorded_trajectory(views)
    assert torch.equal(path, c2w)
    path[0] = 0  # a copy: the scene's cameras are untouched
    assert torch.equal(views.c2w, axis_aligned_rig().float())


def test_scene_trajectory_spirals_around_all_frames(synthetic_scene):
    """As the authors' release: the spiral is fitted to every frame of the scene, not to the 2 train views."""
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    assert scene.source == synthetic_scene and scene.camera_path == "spiral"
    train = scene.split.train
    spiral = scene.trajectory("spiral", n_frames=12)
    assert torch.equal(scene.trajectory(n_frames=12), spiral)  # None: the scene's own camera_path
    assert torch.equal(spiral, llff_spiral(scene.views.c2w, scene.bounds, 12))
    assert not torch.allclose(spiral, llff_spiral(scene.views.c2w[train], scene.bounds[train], 12))
    # Centred on the average pose of all frames (not the origin, which is the average train pose), looking along
    # its -z; the first pose sits r_x along that pose's x axis, r_x the 90th percentile over all 20 frames.
    centre_pose = torch.from_numpy(average_pose(scene.views.c2w.double().numpy()))
    offsets = (scene.views.c2w[:, :, 3].double() - centre_pose[:, 3]) @ centre_pose[:, :3]
    radii = np.percentile(offsets.abs().numpy(), 90, axis=0)
    first = (spiral[0, :, 3].double() - centre_pose[:, 3]) @ centre_pose[:, :3]
    torch.testing.assert_close(first, torch.tensor([radii[0], 0.0, 0.0], dtype=torch.float64), atol=1e-5, rtol=0)
    assert torch.equal(scene.trajectory("recorded"), scene.views.c2w)
    with pytest.raises(ValueError, match="unknown trajectory"):
        scene.trajectory("orbit")


def test_a_scene_of_train_views_only_spirals_around_them(synthetic_scene):
    """Own photos without other frames: the train views are all there is."""
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    train = scene.split.train
    own = Scene(views=subset(scene.views, train), split=Split(train=[0, 1], test=[], val=[0]), scale=scene.scale,
                bounds=scene.bounds[train], source=scene.source)
    assert torch.equal(own.trajectory("spiral", n_frames=12),
                       llff_spiral(scene.views.c2w[train], scene.bounds[train], 12))
