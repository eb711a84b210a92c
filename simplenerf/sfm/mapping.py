"""Structure from motion on photos with unknown poses: pycolmap's incremental mapper, in-process on CPU.

SIFT features (one shared camera by default, an EXIF focal length as the prior where known) -> exhaustive matching
with geometric verification -> incremental mapping. When COLMAP's default thresholds leave photos unregistered (few
photos, small baselines: the few-view case), mapping is retried with relaxed initialisation and triangulation
thresholds (`DEFAULT_ATTEMPTS`), and the attempt that registers the most photos (then the most points) wins. Photos
without verified matches to any other cannot register and are not waited for.

Conventions are COLMAP's (world-to-camera poses, OpenCV axes, pixel centres at +0.5); `simplenerf.sfm.photos` turns
the result into the LLFF layout. The first stage, SIFT and matching, is `simplenerf.sfm.colmap.extract_and_match`, as
for the sparse depth of posed views.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pycolmap
from tqdm import tqdm

from simplenerf.errors import DataError, SfMError
from simplenerf.sfm.colmap import CameraSetup, colmap_log_level, colmap_stage, extract_and_match

ADVICE = (
    "Try photos with more overlap (each part of the scene in 3 or more photos, taken a step apart rather than "
    "turning on the spot), more photos, or larger images (the original photos rather than downscaled copies)."
)
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


@dataclass(frozen=True)
class MapperAttempt:
    """One set of thresholds of COLMAP's incremental mapper (COLMAP's option names in the comments)."""

    name: str
    init_min_num_inliers: int  # mapper.init_min_num_inliers: verified matches of the initial image pair
    init_min_tri_angle: float  # mapper.init_min_tri_angle: degrees, median triangulation angle of the initial pair
    abs_pose_min_num_inliers: int  # mapper.abs_pose_min_num_inliers: 2D-3D inliers to register one more image
    abs_pose_min_inlier_ratio: float  # mapper.abs_pose_min_inlier_ratio
    min_num_matches: int  # min_num_matches: image pairs with fewer verified matches are ignored
    ignore_two_view_tracks: bool  # triangulation.ignore_two_view_tracks (False keeps points seen by two photos)
    min_tri_angle: float  # triangulation.min_angle and mapper.filter_min_tri_angle: degrees, to create/keep a point


# The first attempt is COLMAP's defaults except that points seen in only two photos are kept, as DS-NeRF's SfM does for
# few views: on LLFF fern (images_4) that brought the camera-centre error of 3 photos from 0.87% to 0.60% of the
# camera spread (rotation error 1.2 -> 0.6 deg) and left 20 photos as they were (0.50% -> 0.53%).
DEFAULT_ATTEMPTS = (
    MapperAttempt("default", 100, 16.0, 30, 0.25, 15, False, 1.5),
    MapperAttempt("relaxed", 50, 6.0, 15, 0.15, 10, False, 1.5),
    MapperAttempt("most relaxed", 15, 1.5, 10, 0.1, 8, False, 1.0),
)


@dataclass
class AttemptOutcome:
    """What one mapping attempt gave (its largest model)."""

    name: str
    registered: int
    points: int
    seconds: float
    groups: list[int] = field(default_factory=list)  # registered photos of every model, largest first (>1: disjoint)


@dataclass
class SfMResult:
    """The chosen reconstruction and how it came about."""

    reconstruction: pycolmap.Reconstruction  # the largest model of the winning attempt
    attempt: str  # name of the winning attempt
    attempts: list[AttemptOutcome]  # every attempt run, in order
    keypoints: dict[str, int]  # SIFT keypoints per image name
    verified_pairs: int  # image pairs with geometrically verified matches
    seconds: dict[str, float] = field(default_factory=dict)  # wall time per stage

    def registered_names(self) -> list[str]:
        """Names of the registered images, sorted."""
        return sorted(self.reconstruction.images[i].name for i in self.reconstruction.reg_image_ids())

    def summary(self) -> dict:
        """JSON-ready statistics: counts, mean track length, mean reprojection error, attempts, timings."""
        rec = self.reconstruction
        return {
            "registered_images": rec.num_reg_images(),
            "points": rec.num_points3D(),
            "mean_track_length": float(rec.compute_mean_track_length()),
            "mean_observations_per_image": float(rec.compute_mean_observations_per_reg_image()),
            "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
            "attempt": self.attempt,
            "attempts": [asdict(a) for a in self.attempts],
            "keypoints_per_image": self.keypoints,
            "verified_pairs": self.verified_pairs,
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
        }


def run_sfm(
    image_dir: Path,
    names: Sequence[str],
    work_dir: Path,
    *,
    shared_camera: bool = True,
    camera_model: str = "SIMPLE_RADIAL",
    focal_priors: Sequence[float | None] | None = None,
    max_image_size: int = 3200,
    max_num_features: int = 8192,
    attempts: Sequence[MapperAttempt] = DEFAULT_ATTEMPTS,
    seed: int = 0,
    num_threads: int = -1,
    verbose: bool = False,
    log: Callable[[str], None] = print,
) -> SfMResult:
    """Poses, intrinsics and 3D points of the photos `names` in `image_dir` (all of one size).

    Args:
        image_dir: folder of the photos, already oriented (EXIF orientation applied) and of one size.
        names: file names in `image_dir` to use (>= 2).
        work_dir: an empty scratch folder (COLMAP database and models).
        shared_camera: one camera (intrinsics) for all photos; False: one per photo (photos from several cameras or
            zoom settings).
        camera_model: COLMAP camera model, one of `CAMERA_MODELS` (SIMPLE_RADIAL: f, cx, cy, k; COLMAP's default).
        focal_priors: per photo, the focal length in pixels from EXIF, or None; the shared camera takes the median.
            With a prior COLMAP starts from it (and trusts it); without, it starts from 1.2 x the longer side.
        max_image_size: SIFT runs on photos downscaled to at most this longer side (keypoints are scaled back).
        max_num_features: SIFT keypoints kept per photo.
        attempts: mapper thresholds to try in order; the next is tried only while photos that have verified matches
            remain unregistered.
        seed: seed of COLMAP's RANSAC and mapper.
        num_threads: CPU threads for COLMAP (-1: all cores).
        verbose: let COLMAP print its own log.
        log: where progress lines go.

    Raises:
        DataError: an unknown camera model.
        SfMError: fewer than 2 photos, no photo pair with verified matches, or no attempt that registers 2 photos
            with 3D points; the message says what to try.
    """
    names = list(names)
    if len(names) < 2:
        raise SfMError(f"structure from motion needs at least 2 photos, got {len(names)}. {ADVICE}")
    if camera_model not in CAMERA_MODELS:
        raise DataError(f"camera model {camera_model!r} is not one of {', '.join(CAMERA_MODELS)}")
    database_path = work_dir / "database.db"
    seconds: dict[str, float] = {}
    with colmap_log_level(verbose):
        start = time.perf_counter()
        pairs = len(names) * (len(names) - 1) // 2
        log(f"sfm: SIFT features of {len(names)} photos and exhaustive matching of {pairs} pairs ...")
        cameras = CameraSetup(camera_model, shared=shared_camera, focal_priors=focal_priors)
        found = extract_and_match(database_path, image_dir, names, cameras, max_image_size=max_image_size,
                                  max_num_features=max_num_features, seed=seed, num_threads=num_threads, advice=ADVICE)
        keypoints, matches = found.keypoints, found.pairs
        seconds["features_and_matching"] = time.perf_counter() - start
        log(f"sfm: {min(keypoints.values())}-{max(keypoints.values())} keypoints per photo; {len(matches)} of {pairs} "
            f"pairs have geometrically verified matches ({seconds['features_and_matching']:.0f} s)")
        # Photos without enough verified matches to any other can never register: no attempt waits for them.
        fewest = min(a.min_num_matches for a in attempts)
        reachable = {name for pair, count in matches.items() if count >= fewest for name in pair}
        if not matches:
            raise SfMError(f"no two of the {len(names)} photos share verified SIFT matches, so no camera can be "
                            f"placed. {ADVICE}")

        outcomes: list[AttemptOutcome] = []
        best: pycolmap.Reconstruction | None = None
        best_name = ""
        start_mapping = time.perf_counter()
        for attempt in attempts:
            start = time.perf_counter()
            log(f"sfm: incremental mapping, {attempt.name} thresholds ...")
            reconstruction, groups = _map(database_path, image_dir, work_dir / f"sparse_{len(outcomes)}", attempt,
                                          len(names), seed, num_threads)
            registered = reconstruction.num_reg_images() if reconstruction is not None else 0
            points = reconstruction.num_points3D() if reconstruction is not None else 0
            outcomes.append(AttemptOutcome(attempt.name, registered, points, time.perf_counter() - start, groups))
            log(f"sfm: {attempt.name}: {registered} of {len(names)} photos registered, {points} points "
                f"({outcomes[-1].seconds:.0f} s)")
            if reconstruction is not None and (best is None or (registered, points) > (best.num_reg_images(),
                                                                                      best.num_points3D())):
                best, best_name = reconstruction, attempt.name
            if reconstruction is not None and points > 0 and reachable <= {
                reconstruction.images[i].name for i in reconstruction.reg_image_ids()
            }:
                break
        seconds["mapping"] = time.perf_counter() - start_mapping

    if best is None or best.num_reg_images() < 2 or best.num_points3D() == 0:
        tried = "; ".join(f"{o.name}: {o.registered} registered, {o.points} points" for o in outcomes)
        raise SfMError(
            f"structure from motion could not place at least 2 of the {len(names)} photos with 3D points ({tried}). "
            f"{ADVICE}"
        )
    return SfMResult(best, best_name, outcomes, keypoints, len(matches), seconds)


# ----------------------------------------------------------------------------------------------------------------
# COLMAP stages


def _map(
    database_path: Path,
    image_dir: Path,
    output_dir: Path,
    attempt: MapperAttempt,
    num_images: int,
    seed: int,
    num_threads: int,
) -> tuple[pycolmap.Reconstruction | None, list[int]]:
    """One run of the incremental mapper: its largest model (most registered images), or None, and the registered
    photos of each model it made, largest first (more than one: the photos fall into disjoint groups)."""
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    options.random_seed = seed
    options.min_model_size = 2  # COLMAP drops models under 10 images by default: all of them with few photos
    options.min_num_matches = attempt.min_num_matches
    options.mapper.init_min_num_inliers = attempt.init_min_num_inliers
    options.mapper.init_min_tri_angle = attempt.init_min_tri_angle
    options.mapper.abs_pose_min_num_inliers = attempt.abs_pose_min_num_inliers
    options.mapper.abs_pose_min_inlier_ratio = attempt.abs_pose_min_inlier_ratio
    options.mapper.filter_min_tri_angle = attempt.min_tri_angle
    options.triangulation.min_angle = attempt.min_tri_angle
    options.triangulation.ignore_two_view_tracks = attempt.ignore_two_view_tracks
    output_dir.mkdir(parents=True)
    pycolmap.set_random_seed(seed)
    with tqdm(total=num_images, desc=f"registering ({attempt.name})", unit="photo", leave=False) as bar:

        def registered_more(count: int) -> None:
            bar.update(min(count, bar.total - bar.n))

        with colmap_stage("incremental mapping", ADVICE):
            models = pycolmap.incremental_mapping(
                database_path, image_dir, output_dir, options=options,
                initial_image_pair_callback=lambda: registered_more(2),
                next_image_callback=lambda: registered_more(1),
            )
    if not models:
        return None, []
    groups = sorted((r.num_reg_images() for r in models.values()), reverse=True)
    return max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D())), groups
