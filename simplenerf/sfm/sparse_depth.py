"""Sparse depth from structure-from-motion with known poses: DS-NeRF's depth prior, computed in-process with pycolmap.

Pipeline (DS-NeRF's, as the release runs it: src/prior_generators/sparse_depth/Tester01.py, called by
DepthEstimator02_NeRF_LLFF.py), on the TRAIN views only and at training resolution:
SIFT features -> exhaustive matching with RANSAC geometric verification -> triangulation with the given poses held
fixed (COLMAP's point_triangulator: triangulate, merge/complete tracks, bundle-adjust the points only, filter by
reprojection error and triangulation angle), keeping two-view tracks, which are all there is with two views.

Conventions (see `simplenerf.geometry.rays`):
- Cameras are `intrinsics` [V, 3, 3] (fx, fy, cx, cy) and `c2w` [V, 3, 4] in OpenGL axes (right, up, back) in scene
  units. Pixel (u, v) = (column, row) is the continuous image coordinate (u, v), no +0.5; its ray has camera-frame
  direction [(u - cx) / fx, -(v - cy) / fy, -1], so the ray parameter t is the camera z-depth.
- COLMAP uses OpenCV axes (x right, y down, z forward), world-to-camera poses, and puts the centre of pixel index u at
  the continuous coordinate u + 0.5. Hence: R_cv = R_gl @ diag(1, -1, -1); PINHOLE params [fx, fy, cx + 0.5,
  cy + 0.5]; a COLMAP keypoint (x, y) is our (x - 0.5, y - 0.5), on pixel index (round(x - 0.5), round(y - 0.5)).
  COLMAP's OpenCV camera z is our z-depth.
- Depth of a 3D point in a view = its camera z-depth there. Per view, only depths inside that view's percentile range
  (default [0.5, 99.5]) are kept, which drops the few far-off triangulations of near-parallel rays.

`load_or_compute_sparse_depth` caches the result on disk (an .npz and a JSON summary, written atomically), keyed by a
caller-chosen identity (scene, view indices, resolution), the options and a fingerprint of the inputs.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import logging
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import ArrayLike

from simplenerf.errors import SfMError
from simplenerf.metrics.scores import to_uint8
from simplenerf.sfm import PYCOLMAP_INSTALLED

logger = logging.getLogger(__name__)


@dataclass
class SparseDepth:
    """Sparse depth of one view: M pixels with the depth of the 3D point observed there."""

    pixels: np.ndarray  # [M, 2] float32, (u, v) continuous keypoint location in this project's pixel convention
    depth: np.ndarray  # [M] float32, camera z-depth in scene units (t along the pixel's ray)
    reprojection_error: np.ndarray  # [M] float32, mean reprojection error of the 3D point over its track, pixels
    point_ids: np.ndarray  # [M] int64, 3D point id: the same id in two views is the same 3D point

    def __len__(self) -> int:
        return int(self.depth.shape[0])

    @property
    def pixel_indices(self) -> np.ndarray:
        """[M, 2] int64 (column, row) of the pixel each keypoint lies on (nearest integer coordinate)."""
        return np.rint(self.pixels).astype(np.int64)


# Bump when the output for the same inputs and options changes, so stale caches are recomputed, not reused.
CACHE_VERSION = 1


def compute_sparse_depth(
    images: Sequence[ArrayLike] | ArrayLike,
    intrinsics: ArrayLike,
    c2w: ArrayLike,
    *,
    percentile: tuple[float, float] = (0.5, 99.5),
    min_track_length: int = 2,
    max_num_features: int = 8192,
    guided_matching: bool = False,
    min_tri_angle: float = 1.5,
    max_reprojection_error: float = 4.0,
    seed: int = 0,
    num_threads: int = -1,
    progress: bool = False,
    image_names: Sequence[str] | None = None,
) -> list[SparseDepth]:
    """Triangulates SIFT matches between the views with the given poses held fixed; returns each view's depths.

    Args:
        images: V >= 2 RGB images [H, W, 3], uint8, or float in [0, 1] (a list, or one [V, H, W, 3] array/tensor).
        intrinsics: [V, 3, 3] pinhole intrinsics of these images (fx, fy, cx, cy; no skew).
        c2w: [V, 3, 4] camera-to-world poses, OpenGL axes, scene units.
        percentile: per view, keep depths within these percentiles of that view's depths (DS-NeRF: 0.5, 99.5).
        min_track_length: drop 3D points seen in fewer views (2 keeps two-view tracks, required with 2 views).
        max_num_features: SIFT keypoints kept per image.
        guided_matching: re-match along the verified epipolar geometry (~40% more points on LLFF, ~3x matching time).
        min_tri_angle: degrees; minimum ray angle to create and to keep a point (COLMAP's default 1.5). Lower keeps
            more distant points, whose depth is less certain.
        max_reprojection_error: pixels; points with a larger error in any observation are dropped (COLMAP: 4).
        seed: seed of COLMAP's RANSAC, for reproducible results.
        num_threads: CPU threads for COLMAP (-1: all cores).
        progress: log the stages (logger `simplenerf.sfm.sparse_depth`) and let COLMAP print its own log.
        image_names: the images' own file names (e.g. the scene's), which error messages name instead of the
            temporary copies COLMAP reads (0000.png, ...).

    Returns:
        One `SparseDepth` per view, in input order, sorted by 3D point id.

    Raises:
        SfMError: bad inputs, degenerate poses (zero baseline), an image without SIFT features, or no
            triangulated point.
    """
    images_u8 = _as_uint8_images(images)
    intrinsics_np, c2w_np = _validate_cameras(intrinsics, c2w, images_u8)
    if not 0.0 <= percentile[0] < percentile[1] <= 100.0:
        raise SfMError(f"percentile must satisfy 0 <= low < high <= 100, got {percentile}")
    if min_track_length < 2:
        raise SfMError(f"min_track_length must be >= 2 (a point needs two views), got {min_track_length}")

    try:
        return _compute(images_u8, intrinsics_np, c2w_np, percentile, min_track_length, max_num_features,
                        guided_matching, min_tri_angle, max_reprojection_error, seed, num_threads, progress)
    except SfMError as e:
        if image_names is None:
            raise
        own = {f"{index:04d}.png": str(name) for index, name in enumerate(image_names)}
        raise SfMError(re.sub(r"\b\d{4}\.png\b", lambda m: own.get(m.group(0), m.group(0)), str(e))) from None


def _compute(images_u8, intrinsics_np, c2w_np, percentile, min_track_length, max_num_features, guided_matching,
             min_tri_angle, max_reprojection_error, seed, num_threads, progress) -> list[SparseDepth]:
    # Imported here, not at the top: pycolmap is needed to compute sparse depth, not to read it from the cache.
    from simplenerf.sfm.colmap import CameraSetup, colmap_log_level, colmap_pinhole_params, extract_and_match, log
    from simplenerf.sfm.known_poses import ADVICE, collect, triangulate, verified_pairs, write_images

    with tempfile.TemporaryDirectory(prefix="simplenerf-sfm-") as work, colmap_log_level(verbose=progress):
        work_dir = Path(work)
        start = time.perf_counter()
        names = write_images(images_u8, work_dir / "images")
        database_path = work_dir / "database.db"
        max_size = max(max(image.shape[:2]) for image in images_u8)
        # One PINHOLE camera per view with its own intrinsics, never downscaled: keypoints must be as precise as the
        # training pixels.
        cameras = CameraSetup("PINHOLE", params=[colmap_pinhole_params(k) for k in intrinsics_np])
        extract_and_match(
            database_path, work_dir / "images", names, cameras, max_image_size=max_size,
            max_num_features=max_num_features, seed=seed, num_threads=num_threads, advice=ADVICE,
            guided_matching=guided_matching, relative_pose=True, require_features=True,
        )
        pairs = verified_pairs(database_path, names, c2w_np)
        log(
            progress,
            "sparse depth: SIFT and matching of %d images took %.1f s; %s",
            len(names),
            time.perf_counter() - start,
            ", ".join(p.describe() for p in pairs),
        )
        suspicious = [p for p in pairs if p.disagrees()]
        if suspicious:
            logger.warning(
                "sparse depth: the images disagree with the given poses (%s); check the poses, or the depths will be "
                "wrong",
                ", ".join(p.describe() for p in suspicious),
            )
        if not any(p.num_inliers > 0 for p in pairs):
            raise SfMError(
                f"no image pair has geometrically verified SIFT matches among the {len(names)} views "
                f"({', '.join(p.describe() for p in pairs)}), so no point can be triangulated. {ADVICE}"
            )

        start = time.perf_counter()
        reconstruction = triangulate(
            database_path, work_dir, names, c2w_np, min_tri_angle, max_reprojection_error, seed, num_threads
        )
        log(
            progress,
            "sparse depth: triangulation took %.1f s, %d points",
            time.perf_counter() - start,
            reconstruction.num_points3D(),
        )
        if reconstruction.num_points3D() == 0:
            centres = c2w_np[:, :, 3]
            baseline = np.linalg.norm(centres[:, None] - centres[None], axis=-1).max()
            raise SfMError(
                f"triangulation with the given poses kept 0 points from the verified matches "
                f"({', '.join(p.describe() for p in pairs)}; largest baseline {baseline:.3g} scene units; points "
                f"need a triangulation angle >= {min_tri_angle} deg and reprojection error <= "
                f"{max_reprojection_error} px). Large 'off' angles mean the poses disagree with the images. {ADVICE}"
            )
        views = collect(reconstruction, names, c2w_np, min_track_length, percentile)

    for index, view in enumerate(views):
        if len(view) == 0:
            logger.warning("sparse depth: view %d has no triangulated point (no overlap with the other views?)", index)
    if sum(len(v) for v in views) == 0:
        raise SfMError(
            f"no 3D point is seen in at least {min_track_length} views (min_track_length). {ADVICE}"
        )
    return views


# Bound once: the cache identity follows the real defaults even when tests stub `compute_sparse_depth` out.
_COMPUTE_SIGNATURE = inspect.signature(compute_sparse_depth)


def load_or_compute_sparse_depth(
    cache_dir: str | Path,
    key: Mapping[str, Any],
    images: Sequence[ArrayLike] | ArrayLike,
    intrinsics: ArrayLike,
    c2w: ArrayLike,
    **options: Any,
) -> list[SparseDepth]:
    """`compute_sparse_depth`, cached in `cache_dir`.

    Args:
        cache_dir: folder for the cache files (created if missing).
        key: JSON-serialisable identity of the inputs, e.g. {"scene": "fern", "views": [6, 13], "height": 756,
            "width": 1008}. Stored in the JSON summary for humans; the cache is also keyed by the options (defaults
            included) and a fingerprint of the images and cameras, so a changed input never reuses a stale result.
        images, intrinsics, c2w, options: as for `compute_sparse_depth`.

    Files: `sparse_depth_<hash>.npz` (per-view arrays concatenated, with `counts`) and `sparse_depth_<hash>.json` (key,
    options, per-view point counts and median reprojection errors), each written to a temporary file and renamed.
    """
    bound = _COMPUTE_SIGNATURE.bind(images, intrinsics, c2w, **options)
    bound.apply_defaults()
    # Threads and logging do not change the result, so they must not change the cache identity either.
    result_options = {
        k: v for k, v in bound.arguments.items()
        if k not in ("images", "intrinsics", "c2w", "num_threads", "progress", "image_names")
    }
    result_options = json.loads(json.dumps(result_options))  # tuples -> lists, as they come back from disk
    images_u8 = _as_uint8_images(images)
    intrinsics_np, c2w_np = _validate_cameras(intrinsics, c2w, images_u8)
    identity = {
        "version": CACHE_VERSION,
        "key": json.loads(json.dumps(dict(key), sort_keys=True)),
        "options": result_options,
        "fingerprint": _fingerprint(images_u8, intrinsics_np, c2w_np),
    }
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]
    cache_dir = Path(cache_dir)
    npz_path, json_path = cache_dir / f"sparse_depth_{digest}.npz", cache_dir / f"sparse_depth_{digest}.json"

    cached = _read_cache(npz_path, json_path, identity)
    if cached is not None:
        logger.info("sparse depth: loaded %s", npz_path)
        return cached
    if not PYCOLMAP_INSTALLED:
        raise SfMError(f"sparse depth: no cached result {npz_path} for {identity['key']}, and computing it (SfM) needs "
                       "pycolmap, which is not installed: pip install pycolmap==4.2.1 (pyproject.toml's pin), or copy "
                       "the cache folder from a machine where `simplenerf sparse-depth` ran with the same config")
    views = compute_sparse_depth(images_u8, intrinsics_np, c2w_np, **options)
    try:
        _write_cache(cache_dir, npz_path, json_path, identity, views)
    except OSError as e:  # a read-only or full cache folder: the result is still good, only not kept
        print(f"sparse depth: cannot write the cache {npz_path} ({e.strerror or e}); using the SfM result in memory "
              "(it is computed again next time)", file=sys.stderr, flush=True)
    return views


def _write_cache(cache_dir: Path, npz_path: Path, json_path: Path, identity: dict[str, Any],
                 views: list[SparseDepth]) -> None:
    cache_dir.mkdir(parents=True, exist_ok=True)
    arrays = {
        "counts": np.array([len(v) for v in views], dtype=np.int64),
        "pixels": np.concatenate([v.pixels for v in views]).reshape(-1, 2),
        "depth": np.concatenate([v.depth for v in views]),
        "reprojection_error": np.concatenate([v.reprojection_error for v in views]),
        "point_ids": np.concatenate([v.point_ids for v in views]),
    }
    summary = {
        **identity,
        "views": [
            {
                "num_points": len(v),
                "median_reprojection_error": float(np.median(v.reprojection_error)) if len(v) else None,
                "median_depth": float(np.median(v.depth)) if len(v) else None,
            }
            for v in views
        ],
    }
    # The npz goes first: a JSON summary on disk promises a complete npz next to it.
    _atomic_write(npz_path, lambda f: np.savez(f, **arrays))
    _atomic_write(json_path, lambda f: f.write(json.dumps(summary, indent=2).encode()))
    logger.info("sparse depth: wrote %s", npz_path)


# ----------------------------------------------------------------------------------------------------------------
# Inputs


def _numpy(array: ArrayLike) -> np.ndarray:
    """A numpy copy-or-view of an array, list or torch tensor (on any device; torch is not imported here)."""
    if hasattr(array, "detach"):
        array = array.detach().cpu().numpy()
    return np.asarray(array)


def _as_uint8_images(images: Sequence[ArrayLike] | ArrayLike) -> list[np.ndarray]:
    out = []
    for index, image in enumerate(images):
        array = _numpy(image)
        if array.ndim != 3 or array.shape[2] != 3:
            raise SfMError(f"image {index} has shape {array.shape}, expected [H, W, 3] RGB")
        if array.dtype == np.uint8:
            out.append(np.ascontiguousarray(array))
        elif np.issubdtype(array.dtype, np.floating):
            if not (np.isfinite(array).all() and array.min() >= 0.0 and array.max() <= 1.0):
                raise SfMError(f"image {index} is floating point but not in [0, 1]; pass uint8 or [0, 1]")
            out.append(to_uint8(array))
        else:
            raise SfMError(f"image {index} has dtype {array.dtype}, expected uint8 or float in [0, 1]")
    if len(out) < 2:
        raise SfMError(f"sparse depth needs at least 2 views, got {len(out)}")
    return out


def _validate_cameras(intrinsics: ArrayLike, c2w: ArrayLike, images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Checks shapes and values, and that the poses are rigid with a non-zero baseline; returns float64 copies."""
    intrinsics_np = _numpy(intrinsics).astype(np.float64)
    c2w_np = _numpy(c2w).astype(np.float64)
    n = len(images)
    if intrinsics_np.shape != (n, 3, 3) or c2w_np.shape != (n, 3, 4):
        raise SfMError(
            f"expected intrinsics [{n}, 3, 3] and c2w [{n}, 3, 4] for {n} images, got {intrinsics_np.shape} and "
            f"{c2w_np.shape}"
        )
    if not (np.isfinite(intrinsics_np).all() and np.isfinite(c2w_np).all()):
        raise SfMError("intrinsics or c2w contain NaN or inf")
    for index in range(n):
        k = intrinsics_np[index]
        if k[0, 0] <= 0 or k[1, 1] <= 0 or abs(k[0, 1]) > 1e-6 * k[0, 0]:
            raise SfMError(f"view {index}: intrinsics need fx > 0, fy > 0 and no skew, got\n{k}")
        rotation = c2w_np[index, :, :3]
        if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or np.linalg.det(rotation) < 0:
            raise SfMError(
                f"view {index}: the c2w rotation is not a rotation (orthonormal, det +1):\n{rotation}"
            )
        # COLMAP stores quaternions; snap the float32 round-off to the nearest rotation so it converts exactly.
        u, _, vt = np.linalg.svd(rotation)
        c2w_np[index, :, :3] = u @ vt
    centres = c2w_np[:, :, 3]
    baselines = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    tolerance = 1e-9 * max(1.0, float(np.abs(centres).max()))
    if baselines.max() <= tolerance:
        raise SfMError(
            f"degenerate poses: all {n} camera centres coincide (largest baseline {baselines.max():.3g}), so the "
            f"views have zero baseline and no depth can be triangulated; check c2w (translation in column 3)"
        )
    return intrinsics_np, c2w_np


def _fingerprint(images: list[np.ndarray], intrinsics: np.ndarray, c2w: np.ndarray) -> str:
    digest = hashlib.sha256()
    for image in images:
        digest.update(str(image.shape).encode())
        digest.update(image.tobytes())
    # Rounded, so that float32 and float64 copies of the same cameras share a cache entry (+ 0.0 turns -0.0 into 0.0).
    digest.update((np.round(intrinsics, 4) + 0.0).tobytes())
    digest.update((np.round(c2w, 6) + 0.0).tobytes())
    return digest.hexdigest()


# ----------------------------------------------------------------------------------------------------------------
# COLMAP stages


def _read_cache(npz_path: Path, json_path: Path, identity: dict[str, Any]) -> list[SparseDepth] | None:
    try:
        summary = json.loads(json_path.read_text())
        if any(summary.get(k) != v for k, v in identity.items()):
            return None
        with np.load(npz_path) as data:
            bounds = np.concatenate([[0], np.cumsum(data["counts"])])
            arrays = {k: data[k] for k in ("pixels", "depth", "reprojection_error", "point_ids")}
    except (OSError, ValueError, KeyError):
        return None
    return [SparseDepth(**{k: v[a:b] for k, v in arrays.items()}) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _atomic_write(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Writes through `write(file)` to a temporary file next to `path`, then renames it over `path`."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
