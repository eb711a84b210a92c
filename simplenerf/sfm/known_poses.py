"""The stages of SfM with KNOWN poses that `simplenerf.sfm.sparse_depth` runs after `colmap.extract_and_match`: the
images written for COLMAP, verified-pair diagnostics against the given poses, triangulation with the poses held fixed,
and collecting per-view depths."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from simplenerf.errors import SfMError
from simplenerf.sfm.colmap import colmap_cam_from_world, colmap_stage
from simplenerf.sfm.sparse_depth import SparseDepth

ADVICE = (
    "Try more views, a higher resolution (e.g. images_4 instead of images_8), and check that the poses and "
    "intrinsics are right (OpenGL c2w, scene units, intrinsics of this resolution)."
)


def write_images(images: list[np.ndarray], folder: Path) -> list[str]:
    folder.mkdir()
    names = []
    for index, image in enumerate(images):
        name = f"{index:04d}.png"
        # PNG is lossless, so SIFT sees exactly the training pixels.
        if not cv2.imwrite(str(folder / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise SfMError(f"cannot write {folder / name} for COLMAP")
        names.append(name)
    return names


@dataclass
class PairReport:
    """Matching outcome of one image pair, for progress logs and error messages."""

    views: tuple[int, int]
    num_inliers: int
    rotation_error: float | None  # degrees between COLMAP's estimated relative rotation and the given poses' one
    direction_error: float | None  # degrees between the estimated and the given directions of the baseline
    unchecked: str = ""  # why COLMAP's pose of a matched pair was not compared with the given one (`unchecked_reason`)

    def disagrees(self, max_rotation_error: float = 5.0, max_direction_error: float = 45.0) -> bool:
        """Whether COLMAP's own relative pose contradicts the given one beyond its usual error on short baselines.

        Defaults: on LLFF fern (2 views, images_8) the estimate is off by 1.3 deg and 16 deg; swapping two synthetic
        cameras gives 11 deg and 175 deg.
        """
        if self.rotation_error is None or self.direction_error is None:
            return False
        return self.rotation_error > max_rotation_error or self.direction_error > max_direction_error

    def describe(self) -> str:
        off = f" ({self.unchecked})" if self.unchecked else ""
        if self.rotation_error is not None and self.direction_error is not None:
            off = (
                f" (rotation off {self.rotation_error:.1f} deg, baseline direction off {self.direction_error:.0f} deg)"
            )
        return f"views {self.views}: {self.num_inliers} verified matches{off}"


def verified_pairs(database_path: Path, names: list[str], c2w: np.ndarray) -> list[PairReport]:
    database = pycolmap.Database.open(database_path)
    try:
        view_of = {image.image_id: names.index(image.name) for image in database.read_all_images()}
        pair_ids, geometries = database.read_two_view_geometries()
    finally:
        database.close()
    reports = {}
    for pair_id, geometry in zip(pair_ids, geometries, strict=True):
        id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
        v1, v2 = view_of[id1], view_of[id2]
        rotation_error = direction_error = None
        unchecked = unchecked_reason(geometry)
        if not unchecked:
            pose1, pose2 = colmap_cam_from_world(c2w[v1]), colmap_cam_from_world(c2w[v2])
            rotation = pose2[:, :3] @ pose1[:, :3].T
            translation = pose2[:, 3] - rotation @ pose1[:, 3]
            estimated = geometry.cam2_from_cam1
            cosine = (np.trace(estimated.rotation.matrix().T @ rotation) - 1.0) / 2.0
            rotation_error = float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
            # Scale-free: an essential matrix only fixes the direction of the baseline.
            cosine = unit(estimated.translation) @ unit(translation)
            direction_error = float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
        views = (min(v1, v2), max(v1, v2))
        reports[views] = PairReport(views, len(geometry.inlier_matches), rotation_error, direction_error, unchecked)
    n = len(names)
    # Pairs COLMAP dropped entirely (no match at all) are reported too, so the error lists every pair.
    return [reports.get((a, b), PairReport((a, b), 0, None, None)) for a in range(n) for b in range(a + 1, n)]


# Two-view configurations whose relative pose COLMAP estimates from the essential matrix. A PLANAR (or PANORAMIC)
# pair's pose comes from decomposing a homography, which is ambiguous: on the demo's "objects" scene (a wall and a
# floor fill most pixels) it is off by 4-10 deg and 50-160 deg although the given poses are exact (reprojection
# error 0.03 px), so such pairs are not compared.
POSE_CONFIGS = (pycolmap.TwoViewGeometryConfiguration.CALIBRATED, pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED)

# Fewer verified matches than this and COLMAP's relative pose is too loose to judge the given one by. On LLFF horns
# (images_8, the 54 frames of the held-out reference, 2026-12-07) every pair with at least 30 matches agrees with the
# poses within 3.6 deg and 17 deg; the one pair beyond the limits has 16 (COLMAP's own minimum is 15), 10.9 deg off.
MIN_POSE_INLIERS = 30


def unchecked_reason(geometry) -> str:
    """Why a verified pair's pose says nothing about the given poses, for the progress log; "" if it is compared."""
    if geometry.cam2_from_cam1 is None:
        return "no relative pose: the poses are not checked by it"
    if len(geometry.inlier_matches) < MIN_POSE_INLIERS:
        return f"under {MIN_POSE_INLIERS} matches: too few to check the poses by"
    if geometry.config not in POSE_CONFIGS:
        return "a planar pair: its pose is ambiguous, the poses are not checked by it"
    return ""


def comparable(geometry) -> bool:
    """Whether COLMAP's relative pose of this verified pair is a meaningful check of the given poses."""
    return not unchecked_reason(geometry)


def unit(vector: np.ndarray) -> np.ndarray:
    vector = np.asarray(vector, dtype=np.float64).reshape(3)
    return vector / max(float(np.linalg.norm(vector)), 1e-300)


def triangulate(
    database_path: Path,
    work_dir: Path,
    names: list[str],
    c2w: np.ndarray,
    min_tri_angle: float,
    max_reprojection_error: float,
    seed: int,
    num_threads: int,
) -> pycolmap.Reconstruction:
    database = pycolmap.Database.open(database_path)
    try:
        cameras, images = database.read_all_cameras(), database.read_all_images()
    finally:
        database.close()
    reconstruction = pycolmap.Reconstruction()
    for camera in cameras:
        reconstruction.add_camera_with_trivial_rig(camera)
    for image in images:
        if image.frame_id != image.image_id or image.camera_id not in {c.camera_id for c in cameras}:
            # The trivial rigs and frames made below must carry the database's ids, or COLMAP mixes up the images.
            raise SfMError(f"unexpected COLMAP database layout (image {image}); this pycolmap is unsupported")
        # Same ids as in the database, so COLMAP's correspondence graph refers to these images.
        pose = pycolmap.Rigid3d(colmap_cam_from_world(c2w[names.index(image.name)]))
        reconstruction.add_image_with_trivial_frame(
            pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id), pose
        )

    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    options.random_seed = seed
    options.extract_colors = False
    # The DS-NeRF release: tri_ignore_two_view_tracks=0 (with 2 views every track is a two-view track) and
    # init_min_tri_angle=4; the latter only picks the initial pair of a full reconstruction, inert with fixed poses.
    options.triangulation.ignore_two_view_tracks = False
    options.mapper.init_min_tri_angle = 4.0
    options.triangulation.min_angle = min_tri_angle
    options.mapper.filter_min_tri_angle = min_tri_angle
    options.mapper.filter_max_reproj_error = max_reprojection_error
    output_dir = work_dir / "sparse"
    output_dir.mkdir()
    with colmap_stage("triangulation", ADVICE):
        # Poses stay fixed: point_triangulator sets fix_existing_frames and refines neither poses nor intrinsics.
        return pycolmap.triangulate_points(
            reconstruction, database_path, work_dir / "images", output_dir, options=options, refine_intrinsics=False
        )


def collect(
    reconstruction: pycolmap.Reconstruction,
    names: list[str],
    c2w: np.ndarray,
    min_track_length: int,
    percentile: tuple[float, float],
) -> list[SparseDepth]:
    points = reconstruction.points3D
    by_name = {image.name: image for image in reconstruction.images.values()}
    views = []
    for index, name in enumerate(names):
        image = by_name[name]
        cam_from_world = image.cam_from_world().matrix()
        # Depths are only meaningful along OUR rays if COLMAP kept the poses it was given.
        if np.abs(cam_from_world - colmap_cam_from_world(c2w[index])).max() > 1e-6:
            raise SfMError(f"COLMAP changed the pose of view {index} during triangulation; it must stay fixed")
        pixels, ids = [], []
        for point2d in image.points2D:
            if point2d.has_point3D() and points[point2d.point3D_id].track.length() >= min_track_length:
                pixels.append(point2d.xy)
                ids.append(point2d.point3D_id)
        ids_np = np.array(ids, dtype=np.int64)
        order = np.argsort(ids_np, kind="stable")
        ids_np = ids_np[order]
        pixels_np = np.array(pixels, dtype=np.float64).reshape(-1, 2)[order] - 0.5
        xyz = np.array([points[i].xyz for i in ids_np], dtype=np.float64).reshape(-1, 3)
        depth = xyz @ cam_from_world[2, :3] + cam_from_world[2, 3]
        error = np.array([points[i].error for i in ids_np], dtype=np.float64)
        keep = depth > 0  # COLMAP enforces cheirality; this guards the percentile range against a stray point
        if keep.any():
            low, high = np.percentile(depth[keep], percentile)
            keep &= (depth >= low) & (depth <= high)
        views.append(
            SparseDepth(
                pixels=pixels_np[keep].astype(np.float32),
                depth=depth[keep].astype(np.float32),
                reprojection_error=error[keep].astype(np.float32),
                point_ids=ids_np[keep],
            )
        )
    return views
