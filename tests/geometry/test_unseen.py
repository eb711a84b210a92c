"""Unseen cameras (RegNeRF's unobserved viewpoints) around two or more train cameras."""

import math

import pytest
import torch

from simplenerf.geometry.unseen import mean_rotation, unseen_cameras


def cameras(*centres: tuple[float, float, float], rotation: torch.Tensor | None = None) -> torch.Tensor:
    rotation = torch.eye(3, dtype=torch.float64) if rotation is None else rotation
    return torch.stack([torch.cat([rotation, torch.tensor(c, dtype=torch.float64)[:, None]], 1) for c in centres])


def turn(angle: float) -> torch.Tensor:
    """A rotation about the up axis (y)."""
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=torch.float64)


def test_the_mean_rotation_of_equal_cameras_is_theirs_and_halves_a_turn():
    assert torch.allclose(mean_rotation(cameras((0, 0, 0), (1, 0, 0), rotation=turn(0.3))), turn(0.3))
    both = torch.cat([cameras((0, 0, 0), rotation=turn(0.4)), cameras((1, 0, 0), rotation=turn(-0.2))])
    assert torch.allclose(mean_rotation(both), turn(0.1), atol=1e-12)


def test_without_spread_the_centres_lie_between_the_train_centres():
    c2w = unseen_cameras(cameras((0, 0, 0), (2, 0, 0)), 500, 0.0, torch.Generator().manual_seed(0))
    assert c2w.shape == (500, 3, 4) and torch.equal(c2w[:, :, :3], torch.eye(3, dtype=torch.float64).expand(500, 3, 3))
    x = c2w[:, 0, 3]
    assert torch.all(c2w[:, 1:, 3] == 0) and x.min() >= 0 and x.max() <= 2
    assert x.min() < 0.05 and x.max() > 1.95  # the whole segment is drawn


def test_the_spread_moves_them_within_the_image_plane_by_up_to_spread_times_the_baseline():
    c2w = unseen_cameras(cameras((0, 0, 0), (2, 0, 0)), 2000, 0.5, torch.Generator().manual_seed(1))
    centre = c2w[:, :, 3]
    assert torch.all(centre[:, 2].abs() < 1e-12)  # never along the viewing axis
    off_segment = torch.stack([centre[:, 0].clamp(max=0) + (centre[:, 0] - 2).clamp(min=0), centre[:, 1]], -1)
    assert off_segment.norm(dim=-1).max() <= 1.0 + 1e-12  # 0.5 x the 2-unit distance between the two centres
    assert centre[:, 1].abs().max() > 0.9  # and uses the disc's whole radius


def test_one_train_camera_has_no_unseen_cameras():
    with pytest.raises(ValueError, match="at least 2 train cameras"):
        unseen_cameras(cameras((0, 0, 0)), 4, 1.0, torch.Generator())
