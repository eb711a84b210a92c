"""Your own photos -> a scene in the LLFF layout (`simplenerf process-data`, simplenerf/commands/process_data.py).

Steps:
1. Read every photo (JPEG, PNG, TIFF, BMP, WebP) with its EXIF orientation applied and its EXIF focal length (35 mm
   equivalent, else focal length x focal-plane resolution) as a prior; bring photos of other sizes to the most
   common size (centre crop to its aspect ratio, then resize).
2. Structure from motion (`simplenerf.sfm.mapping`): SIFT, exhaustive matching, incremental mapping with relaxed
   retries.
3. Undistort the registered photos to a pinhole camera with the principal point at the image centre and square
   pixels (what the LLFF loader assumes), at the common size, zoomed just enough to leave no blank border.
4. Write, as LLFF's own tool (imgs2poses / pose_utils.py) does:
   - `images/<name>.png` (undistorted, full size) and `images_N/` (1/N size, area-averaged) for each factor N;
   - `poses_bounds.npy`: one [17] row per registered photo in sorted file-name order: the 3x5 matrix
     [down, right, back, centre, (height, width, focal)] of the camera-to-world pose (LLFF rotation columns, see
     `geometry.poses.poses_to_opengl`) flattened row-major, then near, far = the 0.1 and 99.9 percentiles of the
     camera z-depths of the 3D points seen in that photo. Units and world frame are COLMAP's (arbitrary scale);
     the loader rescales and recentres;
   - `sfm_report.json` (registered and unregistered photos, points, mean track length, reprojection error, camera,
     attempts, timings) and `sfm_top_view.png` (cameras and points from above).
Everything is written into a temporary folder next to the output and renamed at the end: a failure (or Ctrl-C)
writes nothing. The input is never written to: an output that is, contains or lies inside the photo folder is refused,
and `--overwrite` replaces only what an earlier process-data wrote (listed in its marker file), never other files. The
result is judged (`process_checks.judge`): an implausible camera or photos in disjoint groups are reported as
problems, in sfm_report.json and on the terminal.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
import pycolmap
from PIL import Image, UnidentifiedImageError
from tqdm import tqdm

from simplenerf.errors import DataError, SfMError
from simplenerf.geometry.alignment import CameraAlignment, align_cameras
from simplenerf.geometry.poses import poses_to_opengl, to_poses_bounds
from simplenerf.metrics.duplicates import describe_duplicates, near_duplicates, thumbnail
from simplenerf.sfm.colmap import opengl_c2w_of_image
from simplenerf.sfm.mapping import ADVICE, CAMERA_MODELS, SfMResult, run_sfm
from simplenerf.sfm.photo_files import (
    common_size,
    downscaled_size,
    find_photos,
    fit_to_size,
    read_photo,
    undistort,
    undistortion,
)
from simplenerf.sfm.process_checks import (
    MARKER,
    check_output_folder,
    check_writable_parent,
    folder_mode,
    judge,
    replace_output,
)
from simplenerf.sfm.top_view import top_view_picture

BOUND_PERCENTILES = (0.1, 99.9)  # LLFF's pose_utils.save_poses: np.percentile(zs, .1), np.percentile(zs, 99.9)
def depth_bounds(reconstruction: pycolmap.Reconstruction, image: pycolmap.Image,
                 percentiles: tuple[float, float] = BOUND_PERCENTILES) -> tuple[float, float]:
    """(near, far) of a registered image: percentiles of the camera z-depths of the 3D points it observes (LLFF's
    imgs2poses). An image that observes no point (rare) gets the percentiles of every point in front of it.

    Args:
        reconstruction: the SfM model holding the image and its points.
        image: a registered image of `reconstruction`.
        percentiles: (near, far) percentiles, in percent.
    """
    cam_from_world = image.cam_from_world().matrix()
    ids = [p.point3D_id for p in image.points2D if p.has_point3D()]
    if not ids:
        ids = list(reconstruction.point3D_ids())
    xyz = np.array([reconstruction.points3D[i].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    depth = xyz @ cam_from_world[2, :3] + cam_from_world[2, 3]
    depth = depth[depth > 0]
    if len(depth) == 0:
        raise SfMError(f"photo {image.name} sees no 3D point in front of it; the reconstruction is broken. {ADVICE}")
    near, far = np.percentile(depth, percentiles)
    return float(near), float(far)


def process_photos(
    images_dir: str | Path,
    output_dir: str | Path,
    *,
    factors: Sequence[int] = (4, 8),
    shared_camera: bool = True,
    camera_model: str = "SIMPLE_RADIAL",
    max_size: int | None = None,
    sift_max_size: int = 3200,
    max_num_features: int = 8192,
    overwrite: bool = False,
    seed: int = 0,
    num_threads: int = -1,
    verbose: bool = False,
    log: Callable[[str], None] = print,
) -> dict:
    """Photos in `images_dir` -> an LLFF-layout scene in `output_dir` (module docstring); returns the report.

    Args:
        images_dir: folder of photos of one scene.
        output_dir: the scene folder to create (e.g. data/my_scene); must not exist unless `overwrite`.
        factors: downscaling factors N written as images_N/ (the loader's `factor`; 1 is images/ itself).
        shared_camera: one camera for all photos (the same camera and zoom); False: one camera per photo.
        camera_model: COLMAP camera model (simplenerf.sfm.mapping.CAMERA_MODELS); distortion is removed from the output.
        max_size: if given, photos are downscaled so their longer side is at most this (before everything else).
        sift_max_size: SIFT runs on photos downscaled to at most this longer side.
        max_num_features: SIFT keypoints per photo.
        overwrite: replace an existing `output_dir`.
        seed: seed of COLMAP's random choices.
        num_threads: CPU threads for COLMAP (-1: all cores).
        verbose: show COLMAP's own log.
        log: where progress and the report's summary lines go.

    Raises:
        DataError: no such folder, fewer than 2 photos, unreadable photos, an existing output, or structure from
            motion that places fewer than 2 photos or no 3D point; nothing is written then.
    """
    images_dir, output_dir = Path(images_dir), Path(output_dir)
    factors = sorted({int(f) for f in factors})
    if any(f < 1 for f in factors):
        raise DataError(f"factors must be positive integers, got {factors}")
    for option, value in (("max_size", max_size), ("sift_max_size", sift_max_size),
                          ("max_num_features", max_num_features)):
        if value is not None and value < 1:
            raise DataError(f"{option} must be a positive integer, got {value}")
    check_output_folder(images_dir, output_dir, overwrite)
    paths = find_photos(images_dir)
    check_writable_parent(output_dir)
    if camera_model not in CAMERA_MODELS:
        raise DataError(f"camera model {camera_model!r} is not one of {', '.join(CAMERA_MODELS)}")
    try:
        partial = Path(tempfile.mkdtemp(prefix=f".{output_dir.name}.partial-", dir=output_dir.parent))
        partial.chmod(folder_mode())  # mkdtemp's 0700 would become the scene folder's: others could not read it
    except OSError as e:
        raise DataError(f"cannot write the output {output_dir}: {e.strerror or e}") from None
    try:
        report = _process(paths, partial, factors, shared_camera, camera_model, max_size, sift_max_size,
                          max_num_features, seed, num_threads, verbose, log)
        report["output"] = str(output_dir)
        report["problems"] = judge(report)
        (partial / "sfm_report.json").write_text(json.dumps(report, indent=2) + "\n")
        entries = sorted(p.name for p in partial.iterdir())
        files = sorted(p.relative_to(partial).as_posix() for p in partial.rglob("*") if p.is_file())
        (partial / MARKER).write_text(json.dumps({"written_by": "simplenerf process-data",
                                                  "entries": [*entries, MARKER], "files": [*files, MARKER]},
                                                 indent=2) + "\n")
        replace_output(partial, output_dir)
    except OSError as e:
        shutil.rmtree(partial, ignore_errors=True)
        raise DataError(f"cannot write the output {output_dir}: {e.strerror or e}"
                        + (f" ({e.filename})" if e.filename else "")) from None
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    for line in describe(report):
        log(line)
    return report


def _process(
    paths: list[Path],
    out: Path,
    factors: list[int],
    shared_camera: bool,
    camera_model: str,
    max_size: int | None,
    sift_max_size: int,
    max_num_features: int,
    seed: int,
    num_threads: int,
    verbose: bool,
    log: Callable[[str], None],
) -> dict:
    start_all = time.perf_counter()
    work = out / ".work"
    (work / "photos").mkdir(parents=True)
    # Pass 1: sizes only, from the headers (EXIF orientations 5-8 swap width and height).
    sizes = []
    for path in paths:
        try:
            with Image.open(path) as image:
                width, height = image.size
                transposed = image.getexif().get(0x0112, 1) in (5, 6, 7, 8)
        except (OSError, UnidentifiedImageError, ValueError) as e:
            raise DataError(f"cannot read photo {path}: {e}") from e
        sizes.append((width, height) if transposed else (height, width))
    height, width = downscaled_size(*common_size(sizes), max_size)
    names = [f"{p.stem}.png" for p in paths]
    resized, focal_priors, thumbnails = [], [], []
    for path, name, size in tqdm(list(zip(paths, names, sizes, strict=True)), desc="reading photos", unit="photo"):
        photo = read_photo(path)
        image, factor = fit_to_size(photo.image, height, width)
        thumbnails.append(thumbnail(image))
        if size != (height, width):
            resized.append({"photo": path.name, "size": list(size), "scale": round(factor, 6)})
        focal_priors.append(None if photo.focal is None else photo.focal * factor)
        _write_image(work / "photos" / name, image)
    if same := near_duplicates(thumbnails, [p.name for p in paths]):
        raise SfMError(f"photos {describe_duplicates(same)} in {paths[0].parent} are identical or nearly (mean "
                       "difference under 2/255): structure from motion needs photos from different positions; remove "
                       "the copies")
    with_prior = [f for f in focal_priors if f is not None]
    log(f"photos: {len(paths)} from {paths[0].parent}, used at {width}x{height}"
        + (f" ({len(resized)} cropped/resized to that size)" if resized else "")
        + (f"; EXIF focal length of {len(with_prior)} ({np.median(with_prior):.0f} px)" if with_prior else
           "; no EXIF focal length: COLMAP starts from 1.2 x the longer side"))

    sfm = run_sfm(work / "photos", names, work, shared_camera=shared_camera, camera_model=camera_model,
                  focal_priors=focal_priors, max_image_size=sift_max_size, max_num_features=max_num_features,
                  seed=seed, num_threads=num_threads, verbose=verbose, log=log)
    rec = sfm.reconstruction
    by_name = {rec.images[i].name: rec.images[i] for i in rec.reg_image_ids()}
    registered = sorted(by_name)
    unregistered = [p.name for p, n in zip(paths, names, strict=True) if n not in by_name]

    start = time.perf_counter()
    plans = {camera_id: undistortion(camera) for camera_id, camera in rec.cameras.items()
             if any(by_name[n].camera_id == camera_id for n in registered)}
    for factor in factors:
        (out / ("images" if factor == 1 else f"images_{factor}")).mkdir()
    (out / "images").mkdir(exist_ok=True)
    rows_c2w, rows_hwf, rows_bounds = [], [], []
    for name in tqdm(registered, desc="undistorting and writing", unit="photo"):
        image_info = by_name[name]
        plan = plans[image_info.camera_id]
        image = undistort(_read_image(work / "photos" / name), plan)
        _write_image(out / "images" / name, image)
        for factor in factors:
            if factor > 1:
                small = (max(1, round(width / factor)), max(1, round(height / factor)))
                _write_image(out / f"images_{factor}" / name, cv2.resize(image, small, interpolation=cv2.INTER_AREA))
        rows_c2w.append(opengl_c2w_of_image(image_info))
        rows_hwf.append([height, width, plan.focal])
        rows_bounds.append(depth_bounds(rec, image_info))
    poses_bounds = to_poses_bounds(np.stack(rows_c2w), np.array(rows_hwf), np.array(rows_bounds))
    np.save(out / "poses_bounds.npy", poses_bounds)
    seconds_writing = time.perf_counter() - start

    xyz = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)
    colours = np.array([p.color for p in rec.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    stats = sfm.summary()
    title = (f"{len(registered)}/{len(paths)} photos, {stats['points']} points, "
             f"reprojection error {stats['mean_reprojection_error_px']:.2f} px (top view)")
    picture = top_view_picture(np.stack(rows_c2w), xyz, colours, [str(i) for i in range(len(registered))], title)
    _write_image(out / "sfm_top_view.png", picture)
    shutil.rmtree(work)

    report = _report(paths, names, registered, unregistered, resized, focal_priors, sfm, plans, height, width,
                     factors, poses_bounds)
    report["seconds"]["undistort_and_write"] = round(seconds_writing, 2)
    report["seconds"]["total"] = round(time.perf_counter() - start_all, 2)
    return report


def _report(paths: list[Path], names: list[str], registered: list[str], unregistered: list[str], resized: list[dict],
            focal_priors: list[float | None], sfm: SfMResult, plans: dict[int, object], height: int, width: int,
            factors: list[int], poses_bounds: np.ndarray) -> dict:
    stats = sfm.summary()
    cameras = []
    for camera_id, camera in sfm.reconstruction.cameras.items():
        if camera_id in plans:
            cameras.append({
                "model": camera.model.name,
                "params": [round(float(p), 6) for p in camera.params],
                "param_names": camera.params_info,
                "focal_from_exif": bool(camera.has_prior_focal_length),
                "undistorted_focal_px": round(plans[camera_id].focal, 4),
                "largest_undistortion_shift_px": round(plans[camera_id].max_shift, 3),
            })
    priors = [f for f in focal_priors if f is not None]
    return {
        "photos": len(paths),
        "registered": len(registered),
        "registered_photos": [paths[names.index(n)].name for n in registered],
        "unregistered_photos": unregistered,
        "points": stats["points"],
        "mean_track_length": round(stats["mean_track_length"], 4),
        "mean_observations_per_photo": round(stats["mean_observations_per_image"], 2),
        "mean_reprojection_error_px": round(stats["mean_reprojection_error_px"], 4),
        "size": [height, width],
        "factors": factors,
        "resized_photos": resized,
        "exif_focal_px": round(float(np.median(priors)), 2) if priors else None,
        "cameras": cameras,
        "near_far": [round(float(poses_bounds[:, 15].min()), 6), round(float(poses_bounds[:, 16].max()), 6)],
        "attempt": stats["attempt"],
        "attempts": stats["attempts"],
        "verified_pairs": stats["verified_pairs"],
        "keypoints_per_photo": {paths[names.index(n)].name: k for n, k in stats["keypoints_per_image"].items()},
        "seconds": dict(stats["seconds"]),
    }


def describe(report: dict) -> list[str]:
    """The report's summary as terminal lines."""
    lines = [
        f"registered {report['registered']} of {report['photos']} photos "
        f"({report['attempt']} thresholds), {report['points']} points, mean track length "
        f"{report['mean_track_length']:.2f}, mean reprojection error {report['mean_reprojection_error_px']:.2f} px",
    ]
    if report["unregistered_photos"]:
        lines.append(f"not registered (left out of the scene): {', '.join(report['unregistered_photos'])}. {ADVICE}")
    for camera in report["cameras"]:
        lines.append(f"camera {camera['model']} ({camera['param_names']}) = {camera['params']}; undistorted focal "
                     f"{camera['undistorted_focal_px']:.1f} px")
    for problem in report.get("problems", []):
        lines.append(f"WARNING: {problem}; the cameras are probably wrong: check sfm_top_view.png, and the photos "
                     "(one scene, enough overlap)")
    if "output" in report:
        lines.append(f"wrote {report['output']}: images/ ({report['size'][1]}x{report['size'][0]})"
                     + "".join(f", images_{f}/" for f in report["factors"] if f > 1)
                     + ", poses_bounds.npy, sfm_report.json, sfm_top_view.png")
    return lines


def _write_image(path: Path, rgb: np.ndarray) -> None:
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        raise OSError(f"could not read back {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


# ----------------------------------------------------------------------------------------------------------------
# Checking against known poses


def scene_cameras(scene_dir: str | Path) -> dict[str, np.ndarray]:
    """Frame name (file stem) -> c2w [3, 4] (OpenGL, file units) of an LLFF-layout scene, from poses_bounds.npy and
    the sorted names in its first image folder (images/, else the lowest images_N/)."""
    scene_dir = Path(scene_dir)
    folders = sorted((p for p in scene_dir.glob("images*") if p.is_dir()),
                     key=lambda p: 1 if p.name == "images" else int(p.name.split("_")[-1]) if "_" in p.name else 0)
    if not folders or not (scene_dir / "poses_bounds.npy").is_file():
        raise DataError(f"{scene_dir} is not an LLFF-layout scene (poses_bounds.npy and images*/)")
    names = [p.stem for p in sorted(folders[0].iterdir()) if p.suffix.lower() in (".png", ".jpg", ".jpeg")]
    poses_bounds = np.load(scene_dir / "poses_bounds.npy")
    if len(names) != len(poses_bounds):
        raise DataError(f"{folders[0]} has {len(names)} images but poses_bounds.npy has {len(poses_bounds)} rows")
    c2w, _, _ = poses_to_opengl(poses_bounds)
    return dict(zip(names, c2w, strict=True))


def compare_with_reference(scene_dir: str | Path, reference_dir: str | Path) -> tuple[CameraAlignment, list[str]]:
    """Aligns the cameras of a processed scene to a reference scene's (same frame names) and returns the errors
    (`simplenerf.geometry.alignment.align_cameras`) and the frame names compared.

    Args:
        scene_dir: an LLFF-layout scene, e.g. written by `process_photos`.
        reference_dir: an LLFF-layout scene of the same photos with known cameras (e.g. LLFF's own).
    """
    ours, reference = scene_cameras(scene_dir), scene_cameras(reference_dir)
    common = sorted(set(ours) & set(reference))
    if len(common) < 2:
        raise DataError(f"{scene_dir} and {reference_dir} share {len(common)} frame names; at least 2 are needed")
    return align_cameras(np.stack([ours[n] for n in common]), np.stack([reference[n] for n in common])), common
