"""COLMAP in-process (pycolmap 4.x): the conventions between our cameras and COLMAP's, and the stage every use of
structure from motion here starts with: SIFT features and exhaustive matching with geometric verification
(`extract_and_match`), shared by the sparse depth of posed views (`simplenerf.sfm.sparse_depth`, cameras known) and
own photos (`simplenerf.sfm.mapping`, cameras estimated). A failing COLMAP stage raises `SfMError`.

Conventions: COLMAP uses OpenCV axes (x right, y down, z forward), world-to-camera poses, and puts the centre of pixel
index u at the continuous coordinate u + 0.5; ours are OpenGL c2w and pixel centres at integers (see
`simplenerf.sfm.sparse_depth`).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap

from simplenerf.errors import SfMError, SimpleNeRFError

logger = logging.getLogger("simplenerf.sfm.sparse_depth")

# OpenGL camera axes (right, up, back) -> OpenCV/COLMAP axes (right, down, forward).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def colmap_cam_from_world(c2w: np.ndarray) -> np.ndarray:
    """COLMAP's world-to-camera [3, 4] (OpenCV axes) of an OpenGL camera-to-world [3, 4]."""
    rotation_cv = c2w[:3, :3] @ GL_TO_CV
    return np.concatenate([rotation_cv.T, -rotation_cv.T @ c2w[:3, 3:4]], axis=1)


def colmap_pinhole_params(intrinsics: np.ndarray) -> list[float]:
    """COLMAP PINHOLE [fx, fy, cx, cy] of our [3, 3] intrinsics: COLMAP's pixel centres sit at +0.5."""
    return [
        float(intrinsics[0, 0]),
        float(intrinsics[1, 1]),
        float(intrinsics[0, 2]) + 0.5,
        float(intrinsics[1, 2]) + 0.5,
    ]


def opengl_c2w_of_image(image: pycolmap.Image) -> np.ndarray:
    """[3, 4] camera-to-world in OpenGL axes (right, up, back) of a registered COLMAP image."""
    cam_from_world = image.cam_from_world().matrix()
    rotation = cam_from_world[:, :3].T  # camera-to-world rotation, OpenCV axes
    centre = -rotation @ cam_from_world[:, 3]
    return np.concatenate([rotation @ GL_TO_CV, centre[:, None]], axis=1)


@contextlib.contextmanager
def colmap_log_level(verbose: bool) -> Iterator[None]:
    """COLMAP logs every stage at INFO through glog; keep only its errors unless asked for progress."""
    previous = pycolmap.logging.minloglevel
    if not verbose:
        pycolmap.logging.minloglevel = 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous


def log(progress: bool, message: str, *args: object) -> None:
    logger.log(logging.INFO if progress else logging.DEBUG, message, *args)


@contextlib.contextmanager
def colmap_stage(stage: str, advice: str) -> Iterator[None]:
    """Turns a failing COLMAP check (raised by pycolmap as a bare RuntimeError/ValueError) into one `SfMError` that
    names the stage and ends with `advice`."""
    try:
        yield
    except SimpleNeRFError:
        raise
    except (RuntimeError, ValueError) as e:
        raise SfMError(f"COLMAP failed during {stage}: {e}. {advice}") from e


@dataclass(frozen=True)
class CameraSetup:
    """How COLMAP is told about the cameras of the images."""

    model: str  # COLMAP camera model, e.g. PINHOLE (known intrinsics) or SIMPLE_RADIAL (estimated)
    shared: bool = False  # one camera for every image (else one per image)
    params: Sequence[Sequence[float]] | None = None  # per image, its known camera parameters (kept fixed)
    focal_priors: Sequence[float | None] | None = None  # per image, a focal length prior in pixels, or None


@dataclass
class Matches:
    """What feature extraction and matching found."""

    keypoints: dict[str, int]  # SIFT keypoints per image name
    pairs: dict[tuple[str, str], int]  # geometrically verified matches per image pair with any


def extract_and_match(
    database_path: Path,
    image_dir: Path,
    names: list[str],
    cameras: CameraSetup,
    *,
    max_image_size: int,
    max_num_features: int,
    seed: int,
    num_threads: int,
    advice: str,
    guided_matching: bool = False,
    relative_pose: bool = False,
    require_features: bool = False,
) -> Matches:
    """SIFT features of the images `names` in `image_dir` and exhaustive matching with RANSAC verification, written to
    the COLMAP database `database_path` (created).

    Args:
        database_path: the database file to create.
        image_dir: folder of the images.
        names: file names in `image_dir` to use.
        cameras: the cameras' model, sharing, known parameters or focal priors.
        max_image_size: SIFT runs on images downscaled to at most this longer side (keypoints are scaled back).
        max_num_features: SIFT keypoints kept per image.
        seed: seed of COLMAP's RANSAC.
        num_threads: CPU threads for COLMAP (-1: all cores).
        advice: what to try, ending every error's message.
        guided_matching: re-match along the verified epipolar geometry.
        relative_pose: also estimate each verified pair's relative pose (diagnostics of given poses).
        require_features: every image must have SIFT features (else one that has none is an error).

    Raises:
        SfMError: COLMAP fails, cannot read an image, or (`require_features`) finds no feature in one.
    """
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cameras.model
    if cameras.params is not None:
        # Every camera is created with image 0's parameters and then overwritten with its image's own below.
        reader.camera_params = ",".join(str(p) for p in cameras.params[0])
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.max_image_size = max_image_size
    extraction.sift.max_num_features = max_num_features
    with colmap_stage("SIFT feature extraction", advice):
        pycolmap.extract_features(
            database_path,
            image_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE if cameras.shared else pycolmap.CameraMode.PER_IMAGE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
    database = pycolmap.Database.open(database_path)
    try:
        images = {image.name: image for image in database.read_all_images()}
        missing = [f"{index} ({name})" for index, name in enumerate(names) if name not in images]
        if missing:
            raise SfMError(f"COLMAP could not read image {', '.join(missing)}")
        keypoints = {n: int(database.num_keypoints_for_image(images[n].image_id)) for n in names}
        blank = [f"{index} ({name})" for index, name in enumerate(names) if keypoints[name] == 0]
        if require_features and blank:
            raise SfMError(f"image {', '.join(blank)} has no SIFT features: textureless (e.g. a constant colour), "
                           f"blank or too small? {advice}")
        _set_cameras(database, [images[n].camera_id for n in names], cameras)
    finally:
        database.close()

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.guided_matching = guided_matching
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    verification.compute_relative_pose = relative_pose
    pycolmap.set_random_seed(seed)
    with colmap_stage("exhaustive matching", advice):
        pycolmap.match_exhaustive(
            database_path, matching_options=matching, verification_options=verification, device=pycolmap.Device.cpu
        )
    database = pycolmap.Database.open(database_path)
    try:
        name_of = {image.image_id: image.name for image in database.read_all_images()}
        pair_ids, geometries = database.read_two_view_geometries()
    finally:
        database.close()
    pairs = {}
    for pair_id, geometry in zip(pair_ids, geometries, strict=True):
        if len(geometry.inlier_matches):
            id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
            pairs[(name_of[id1], name_of[id2])] = len(geometry.inlier_matches)
    return Matches(keypoints, pairs)


def _set_cameras(database: pycolmap.Database, camera_ids: list[int], cameras: CameraSetup) -> None:
    """Known parameters per image, or the focal priors: per camera, the median over the images it serves."""
    if cameras.params is not None:
        for camera_id, params in zip(camera_ids, cameras.params, strict=True):
            camera = database.read_camera(camera_id)
            camera.params = list(params)
            database.update_camera(camera)
        return
    by_camera: dict[int, list[float]] = {}
    for camera_id, prior in zip(camera_ids, cameras.focal_priors or [None] * len(camera_ids), strict=True):
        if prior is not None:
            by_camera.setdefault(camera_id, []).append(float(prior))
    for camera_id, values in by_camera.items():
        camera = database.read_camera(camera_id)
        params = np.array(camera.params)
        params[list(camera.focal_length_idxs())] = float(np.median(values))
        camera.params = params
        camera.has_prior_focal_length = True
        database.update_camera(camera)
