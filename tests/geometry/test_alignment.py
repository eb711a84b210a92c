"""Camera alignment (Umeyama): exact recovery of a known similarity, optimality, and the orientation errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from simplenerf.geometry.alignment import align_cameras, rotation_angle, umeyama


def random_cameras(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    return np.concatenate([rotations, rng.normal(size=(n, 3, 1))], axis=2)


def transform(c2w: np.ndarray, scale: float, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The same cameras in a world moved by x -> scale R x + t."""
    return np.concatenate([rotation @ c2w[:, :, :3], (scale * c2w[:, :, 3] @ rotation.T + translation)[:, :, None]],
                          axis=2)


def test_umeyama_recovers_an_exact_similarity() -> None:
    source = np.random.default_rng(0).normal(size=(6, 3))
    rotation = Rotation.from_euler("xyz", [20, -35, 70], degrees=True).as_matrix()
    target = 2.5 * source @ rotation.T + np.array([1.0, -2.0, 0.5])
    scale, r, t = umeyama(source, target)
    assert scale == pytest.approx(2.5, abs=1e-12)
    np.testing.assert_allclose(r, rotation, atol=1e-12)
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-12)


def test_umeyama_is_the_least_squares_similarity() -> None:
    # Against a generic optimiser over (log scale, rotation vector, translation) on noisy correspondences.
    rng = np.random.default_rng(1)
    source = rng.normal(size=(8, 3))
    target = 0.7 * source @ Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix().T + 3.0 + 0.05 * rng.normal(size=(8, 3))
    scale, r, t = umeyama(source, target)
    cost = ((target - scale * source @ r.T - t) ** 2).sum()

    def objective(p: np.ndarray) -> float:
        rot = Rotation.from_rotvec(p[1:4]).as_matrix()
        return float(((target - np.exp(p[0]) * source @ rot.T - p[4:]) ** 2).sum())

    best = minimize(objective, np.zeros(7), method="BFGS", options={"gtol": 1e-12})
    assert cost <= best.fun + 1e-9
    assert cost == pytest.approx(best.fun, rel=1e-6)


def test_umeyama_never_returns_a_reflection() -> None:
    source = np.random.default_rng(2).normal(size=(5, 3))
    target = source * np.array([1.0, 1.0, -1.0])  # a mirror image: the best rotation is not the mirror
    _, r, _ = umeyama(source, target)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)


def test_align_cameras_of_a_moved_world_has_no_error() -> None:
    reference = random_cameras(7, seed=3)
    rotation = Rotation.from_euler("zyx", [100, 10, -40], degrees=True).as_matrix()
    # Estimated = reference seen in another frame: the inverse similarity brings it back exactly.
    estimated = transform(reference, 0.2, rotation, np.array([5.0, 0.0, -1.0]))
    alignment = align_cameras(estimated, reference)
    assert alignment.scale == pytest.approx(5.0, rel=1e-12)
    assert alignment.rms == pytest.approx(0.0, abs=1e-12)
    assert alignment.rotation_error_deg == pytest.approx(0.0, abs=1e-5)
    assert alignment.direction_error_deg == pytest.approx(0.0, abs=1e-5)
    centres = reference[:, :, 3]
    assert alignment.spread == pytest.approx(np.sqrt(((centres - centres.mean(0)) ** 2).sum(1).mean()), rel=1e-12)


def test_align_cameras_hand_computed_errors() -> None:
    # Four reference cameras on a square of side 2 (spread sqrt(2), extent 2sqrt(2)), all looking along -z.
    centres = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    reference = np.concatenate([np.broadcast_to(np.eye(3), (4, 3, 3)), centres[:, :, None]], axis=2)
    # Estimated: the centres lifted to z = 0.1 x y (+-0.1, alternating). No rotation or translation helps (by
    # symmetry); the best scale is s = sum(ref . est) / sum |est|^2 = 2 / 2.01, which leaves every camera
    # sqrt(2 (1 - s)^2 + 0.01 s^2) off.
    estimated = reference.copy()
    estimated[:, 2, 3] = 0.1 * centres[:, 0] * centres[:, 1]
    # Camera 0 also turned by 4 degrees about y: the best common rotation of the orientations turns by theta with
    # tan(theta) = sin 4 / (3 + cos 4) (maximising 3 cos(theta) + cos(theta - 4)), which leaves camera 0 4 - theta off.
    estimated[0, :, :3] = Rotation.from_euler("y", 4, degrees=True).as_matrix()
    alignment = align_cameras(estimated, reference)
    s = 2 / 2.01
    error = np.sqrt(2 * (1 - s) ** 2 + 0.01 * s**2)
    assert alignment.scale == pytest.approx(s, abs=1e-12)
    np.testing.assert_allclose(alignment.rotation, np.eye(3), atol=1e-12)
    assert alignment.rms == pytest.approx(error, abs=1e-12)
    assert alignment.max_error == pytest.approx(error, abs=1e-12)
    assert alignment.spread == pytest.approx(np.sqrt(2), abs=1e-12)
    assert alignment.extent == pytest.approx(np.sqrt(8), abs=1e-12)
    assert alignment.rms_percent == pytest.approx(100 * error / np.sqrt(2), abs=1e-10)
    assert alignment.rms_percent_of_extent == pytest.approx(100 * error / np.sqrt(8), abs=1e-10)
    theta = np.degrees(np.arctan2(np.sin(np.radians(4)), 3 + np.cos(np.radians(4))))
    assert alignment.rotation_error_deg == pytest.approx(4 - theta, abs=1e-6)


def test_two_cameras_direction_error_is_the_baseline_turn() -> None:
    # With 2 cameras the centres always align; the baseline direction seen from camera 0 shows a turned camera.
    reference = np.concatenate([np.broadcast_to(np.eye(3), (2, 3, 3)), np.array([[0.0, 0, 0], [1, 0, 0]])[:, :, None]],
                               axis=2)
    estimated = reference.copy()
    estimated[0, :, :3] = Rotation.from_euler("y", 6, degrees=True).as_matrix()
    alignment = align_cameras(estimated, reference)
    assert alignment.rms == pytest.approx(0.0, abs=1e-12)
    assert alignment.direction_error_deg == pytest.approx(6.0, abs=1e-9)
    assert alignment.rotation_error_deg == pytest.approx(3.0, abs=1e-6)


def test_rotation_angle_and_bad_inputs() -> None:
    assert rotation_angle(Rotation.from_euler("x", 30, degrees=True).as_matrix()) == pytest.approx(30.0)
    with pytest.raises(ValueError, match="coincide"):
        align_cameras(random_cameras(3, 0), np.concatenate([np.broadcast_to(np.eye(3), (3, 3, 3)),
                                                            np.zeros((3, 3, 1))], axis=2))
    with pytest.raises(ValueError, match="N >= 2"):
        align_cameras(random_cameras(1, 0), random_cameras(1, 1))
