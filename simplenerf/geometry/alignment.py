"""How far recovered cameras are from reference cameras, up to the similarity SfM cannot know (Umeyama 1991).

Structure from motion recovers poses up to a similarity (scale, rotation, translation). `align_cameras` finds the
similarity that best maps the estimated camera centres onto the reference ones (least squares, Umeyama) and reports
the remaining centre error relative to the spread of the reference cameras, plus scale-free orientation errors that
also mean something with 2 cameras (where any similarity maps 2 centres exactly).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity (s, R, t) minimising sum_i || target_i - (s R source_i + t) ||^2 (Umeyama 1991).

    Args:
        source: [N, 3] points.
        target: [N, 3] corresponding points, N >= 2 (N >= 3 not collinear for a unique rotation).
        with_scale: estimate the scale (False: s = 1, a rigid motion).

    Returns:
        s (float), R [3, 3] (a rotation, det +1), t [3].
    """
    source, target = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 2:
        raise ValueError(f"need two [N, 3] arrays with N >= 2, got {source.shape} and {target.shape}")
    mean_s, mean_t = source.mean(0), target.mean(0)
    xs, xt = source - mean_s, target - mean_t
    variance = (xs**2).sum() / len(source)
    if variance == 0:
        raise ValueError("the source points all coincide: no similarity is defined")
    u, d, vt = np.linalg.svd(xt.T @ xs / len(source))
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    rotation = u @ np.diag(sign) @ vt
    scale = float((d * sign).sum() / variance) if with_scale else 1.0
    return scale, rotation, mean_t - scale * rotation @ mean_s


def rotation_angle(rotation: np.ndarray) -> np.ndarray:
    """Angle in degrees of rotation matrices [..., 3, 3]."""
    cosine = (np.trace(rotation, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


@dataclass
class CameraAlignment:
    """Errors of estimated cameras against reference cameras after the best similarity (reference units)."""

    scale: float  # s of the similarity estimated -> reference
    rotation: np.ndarray  # [3, 3] R of the similarity
    translation: np.ndarray  # [3] t of the similarity
    rms: float  # root mean square distance between aligned estimated and reference centres
    max_error: float  # largest such distance
    spread: float  # camera spread: root mean square distance of the reference centres from their centroid
    extent: float  # largest distance between two reference centres
    rotation_error_deg: float  # largest angle between a camera's orientation and the reference, after the best
    # common rotation of the orientations (independent of the centres)
    direction_error_deg: float  # mean over camera pairs of the angle between the estimated and the reference
    # direction from one camera to the other, in the first camera's frame (scale-free)

    @property
    def rms_percent(self) -> float:
        """`rms` in percent of `spread`."""
        return 100.0 * self.rms / self.spread

    @property
    def rms_percent_of_extent(self) -> float:
        """`rms` in percent of `extent`."""
        return 100.0 * self.rms / self.extent


def align_cameras(c2w_estimated: np.ndarray, c2w_reference: np.ndarray) -> CameraAlignment:
    """Aligns estimated cameras to reference cameras (Umeyama on the centres) and measures what remains.

    Args:
        c2w_estimated: [N, 3, 4] camera-to-world poses from SfM, N >= 2.
        c2w_reference: [N, 3, 4] the same cameras' reference poses, in the same order and the same axis convention
            (e.g. both OpenGL).
    """
    est, ref = np.asarray(c2w_estimated, dtype=np.float64), np.asarray(c2w_reference, dtype=np.float64)
    if est.shape != ref.shape or est.ndim != 3 or est.shape[1:] != (3, 4) or len(est) < 2:
        raise ValueError(f"need two [N, 3, 4] pose arrays with N >= 2, got {est.shape} and {ref.shape}")
    centres_est, centres_ref = est[:, :, 3], ref[:, :, 3]
    spread = float(np.sqrt(((centres_ref - centres_ref.mean(0)) ** 2).sum(1).mean()))
    if spread == 0:
        raise ValueError("the reference camera centres all coincide: the spread is 0")
    scale, rotation, translation = umeyama(centres_est, centres_ref)
    errors = np.linalg.norm(centres_est @ (scale * rotation).T + translation - centres_ref, axis=1)

    # Orientations: the rotation Q minimising sum_i ||Q R_est_i - R_ref_i||_F (projection of sum R_ref R_est^T).
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", ref[:, :, :3], est[:, :, :3]))
    q = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    rotation_errors = rotation_angle(np.einsum("nji,jk,nkl->nil", ref[:, :, :3], q, est[:, :, :3]))

    direction_errors = []
    for i in range(len(est)):
        for j in range(i + 1, len(est)):
            d_est = est[i, :, :3].T @ (centres_est[j] - centres_est[i])
            d_ref = ref[i, :, :3].T @ (centres_ref[j] - centres_ref[i])
            cosine = d_est @ d_ref / max(np.linalg.norm(d_est) * np.linalg.norm(d_ref), 1e-300)
            direction_errors.append(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
    return CameraAlignment(
        scale=scale,
        rotation=rotation,
        translation=translation,
        rms=float(np.sqrt((errors**2).mean())),
        max_error=float(errors.max()),
        spread=spread,
        extent=float(np.linalg.norm(centres_ref[:, None] - centres_ref[None], axis=-1).max()),
        rotation_error_deg=float(rotation_errors.max()),
        direction_error_deg=float(np.mean(direction_errors)),
    )
