"""Tests of sfm.sparse_depth: COLMAP's pixel convention, pose conversion, exact synthetic depths, errors, cache.

The synthetic scene (simplenerf.synthetic.generate) has exact depth maps, so the triangulated depths are checked against
ground truth, and the same 3D point seen in two views is checked to reproject onto its keypoint with our own camera
model (simplenerf.geometry.rays), which catches any half-pixel or axis mistake in the conversion to COLMAP.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pycolmap
import pytest
import torch

import simplenerf.sfm.sparse_depth as sparse_depth_module
from simplenerf.data.llff import load_llff_scene, subset
from simplenerf.errors import SfMError
from simplenerf.geometry.rays import pixel_rays, project
from simplenerf.sfm.colmap import colmap_cam_from_world, colmap_pinhole_params
from simplenerf.sfm.sparse_depth import SparseDepth, compute_sparse_depth, load_or_compute_sparse_depth
from simplenerf.synthetic.generate import make_synthetic_scene
from tests.conftest import require_shared

# SIFT needs more pixels than the 48x64 default test scene: at 240x320 it finds a few hundred points per view pair.
HEIGHT, WIDTH = 240, 320


def _uint8(images: torch.Tensor) -> list[np.ndarray]:
    return [np.rint(im.numpy() * 255.0).astype(np.uint8) for im in images]


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> dict[int, tuple[object, list[SparseDepth]]]:
    """Train views (scaled and recentred by the LLFF loader) and their sparse depths, for 2 and 3 views."""
    root = make_synthetic_scene(tmp_path_factory.mktemp("sparse") / "scene", height=HEIGHT, width=WIDTH, n_frames=8)
    out = {}
    for n_views in (2, 3):
        scene = load_llff_scene(root, factor=1, n_views=n_views)
        views = subset(scene.views, scene.split.train)
        out[n_views] = (views, compute_sparse_depth(_uint8(views.images), views.intrinsics, views.c2w))
    return out


def test_colmap_sift_keypoints_sit_at_pixel_index_plus_half() -> None:
    # Blobs centred on integer pixel indices (our continuous coordinates) come back from COLMAP at +0.5: the fact
    # that the PINHOLE principal point shift and the keypoint shift of `sparse_depth` rest on.
    yy, xx = np.mgrid[0:160, 0:160].astype(np.float64)
    centres = [(u, v) for u in range(20, 141, 30) for v in range(25, 146, 30)]
    image = sum(np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 2.5**2)) for u, v in centres)
    extractor = pycolmap.FeatureExtractor.create(pycolmap.FeatureExtractionOptions(), device=pycolmap.Device.cpu)
    keypoints = pycolmap.keypoints_to_matrix(
        extractor.extract_from_uint8_array(np.clip(image * 255, 0, 255).astype(np.uint8))[0]
    )
    offsets = []
    for u, v in centres:
        nearest = np.argmin(np.hypot(keypoints[:, 0] - u, keypoints[:, 1] - v))
        offsets.append(keypoints[nearest, :2] - (u, v))
    np.testing.assert_allclose(np.array(offsets), 0.5, atol=0.02)


def test_colmap_camera_projects_like_our_camera_plus_half_pixel() -> None:
    rng = np.random.default_rng(0)
    axis_angle = rng.normal(size=3) * 0.3
    rotation = pycolmap.Rotation3d(axis_angle).matrix()
    c2w = np.concatenate([rotation, rng.normal(size=(3, 1))], axis=1)
    intrinsics = np.array([[500.0, 0.0, 160.3], [0.0, 480.0, 119.7], [0.0, 0.0, 1.0]])
    # Points in front of the OpenGL camera (negative camera z).
    cam_points = np.stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), -rng.uniform(2, 6, 50)], axis=1)
    world = cam_points @ c2w[:, :3].T + c2w[:, 3]

    ours, z = project(torch.from_numpy(world), torch.from_numpy(intrinsics)[None], torch.from_numpy(c2w)[None])
    camera = pycolmap.Camera(model="PINHOLE", width=320, height=240, params=colmap_pinhole_params(intrinsics))
    cam_from_world = pycolmap.Rigid3d(colmap_cam_from_world(c2w))
    colmap_cam = cam_from_world * world
    np.testing.assert_allclose(camera.img_from_cam(colmap_cam), ours.numpy() + 0.5, atol=1e-9)
    # COLMAP's camera z is our z-depth.
    np.testing.assert_allclose(colmap_cam[:, 2], z.numpy(), atol=1e-12)


@pytest.mark.parametrize("n_views", [2, 3])
def test_synthetic_sparse_depth_matches_exact_depth(synthetic: dict, n_views: int) -> None:
    views, result = synthetic[n_views]
    assert len(result) == n_views
    for index, view in enumerate(result):
        assert len(view) > 100, f"view {index}: only {len(view)} points"
        assert view.pixels.shape == (len(view), 2) and view.point_ids.shape == (len(view),)
        columns, rows = view.pixel_indices.T
        assert (columns >= 0).all() and (columns < WIDTH).all() and (rows >= 0).all() and (rows < HEIGHT).all()
        exact = views.depths[index].numpy()[rows, columns]
        relative = np.abs(view.depth - exact) / exact
        assert np.median(relative) < 0.01, f"view {index}: median relative depth error {np.median(relative):.4f}"
        # A few keypoints sit on occlusion edges, where the nearest pixel sees the other surface.
        assert np.mean(relative < 0.05) > 0.9
        assert np.median(view.reprojection_error) < 0.5
    if n_views == 2:
        # Two views: every point is a two-view track, so (up to each view's percentile cut) both see the same points.
        common = np.intersect1d(result[0].point_ids, result[1].point_ids)
        assert len(common) >= 0.95 * max(len(result[0]), len(result[1]))


@pytest.mark.parametrize("n_views", [2, 3])
def test_synthetic_points_reproject_onto_their_keypoints(synthetic: dict, n_views: int) -> None:
    # A point placed at depth along view a's ray through its keypoint must land on its keypoint in view b: this uses
    # only our camera model, so a half-pixel or axis error in the COLMAP conversion would show here.
    views, result = synthetic[n_views]
    checked = 0
    for a in range(n_views):
        for b in range(n_views):
            if a == b:
                continue
            _, in_a, in_b = np.intersect1d(result[a].point_ids, result[b].point_ids, return_indices=True)
            origins, directions = pixel_rays(
                views.intrinsics[a : a + 1].double(),
                views.c2w[a : a + 1].double(),
                torch.from_numpy(result[a].pixels[in_a]).double(),
            )
            points = origins + torch.from_numpy(result[a].depth[in_a]).double()[:, None] * directions
            uv, z = project(points, views.intrinsics[b : b + 1].double(), views.c2w[b : b + 1].double())
            distance = np.linalg.norm(uv.numpy() - result[b].pixels[in_b], axis=1)
            error = result[a].reprojection_error[in_a]
            assert np.median(distance) < 0.1, f"views {a}->{b}: median {np.median(distance):.3f} px"
            # The distance is the 3D point's reprojection errors in a and b (at most 3x its mean error with <= 3
            # views), so points COLMAP fits well must land within a pixel; the rest are the few poor matches.
            assert (distance[error < 0.25] < 1.0).all()
            assert np.mean(distance < 1.0) > 0.95
            np.testing.assert_allclose(z.numpy(), result[b].depth[in_b], rtol=0.02)
            checked += len(in_a)
    assert checked > 0


def test_textureless_images_raise_about_features() -> None:
    images = [np.full((HEIGHT, WIDTH, 3), 128, dtype=np.uint8)] * 2
    intrinsics = np.stack([np.array([[300.0, 0, WIDTH / 2], [0, 300.0, HEIGHT / 2], [0, 0, 1]])] * 2)
    c2w = np.stack([np.eye(3, 4), np.eye(3, 4)])
    c2w[1, 0, 3] = 0.5
    with pytest.raises(SfMError, match="no SIFT features"):
        compute_sparse_depth(images, intrinsics, c2w)


def test_identical_camera_centres_raise_about_baseline(synthetic: dict) -> None:
    views, _ = synthetic[2]
    c2w = views.c2w.clone()
    c2w[1, :, 3] = c2w[0, :, 3]
    with pytest.raises(SfMError, match="baseline"):
        compute_sparse_depth(_uint8(views.images), views.intrinsics, c2w)


def test_no_surviving_point_raises_with_advice(synthetic: dict) -> None:
    # An impossible triangulation angle rejects every point: the error must come from us, with advice, not COLMAP.
    views, _ = synthetic[2]
    with pytest.raises(SfMError, match="kept 0 points.*more views"):
        compute_sparse_depth(_uint8(views.images), views.intrinsics, views.c2w, min_tri_angle=60.0)


def test_bad_inputs_raise_clearly(synthetic: dict) -> None:
    views, _ = synthetic[2]
    images = _uint8(views.images)
    with pytest.raises(SfMError, match="at least 2 views"):
        compute_sparse_depth(images[:1], views.intrinsics[:1], views.c2w[:1])
    with pytest.raises(SfMError, match="expected intrinsics"):
        compute_sparse_depth(images, views.intrinsics[:1], views.c2w)
    scaled = views.c2w.clone()
    scaled[0, :, :3] *= 2.0
    with pytest.raises(SfMError, match="not a rotation"):
        compute_sparse_depth(images, views.intrinsics, scaled)


def test_cache_round_trip(synthetic: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    views, _ = synthetic[2]
    images = _uint8(views.images)
    key = {"scene": "synthetic", "views": [3, 5], "height": HEIGHT, "width": WIDTH}
    first = load_or_compute_sparse_depth(tmp_path, key, images, views.intrinsics, views.c2w)
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".json", ".npz"]  # no temporary files left behind
    summary = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert summary["key"] == key
    assert [v["num_points"] for v in summary["views"]] == [len(v) for v in first]

    def no_recompute(*args: object, **kwargs: object) -> None:
        raise AssertionError("the cache was not used")

    monkeypatch.setattr(sparse_depth_module, "compute_sparse_depth", no_recompute)
    # num_threads and progress do not change the result, so they hit the same cache entry.
    second = load_or_compute_sparse_depth(tmp_path, key, images, views.intrinsics, views.c2w, num_threads=1)
    for a, b in zip(first, second, strict=True):
        for name in ("pixels", "depth", "reprojection_error", "point_ids"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    with pytest.raises(AssertionError, match="cache was not used"):
        load_or_compute_sparse_depth(tmp_path, key, images, views.intrinsics, views.c2w, percentile=(1.0, 99.0))


WITHOUT_PYCOLMAP = """
import sys
sys.modules["pycolmap"] = None  # `import pycolmap` raises ModuleNotFoundError, as on a machine without it
import torch
import simplenerf.data.scene  # the fit's path to the sparse depth imports without pycolmap
from simplenerf.errors import SfMError
from simplenerf.sfm.sparse_depth import load_or_compute_sparse_depth
cache, inputs = sys.argv[1], torch.load(sys.argv[2])
inputs["images"] = list(inputs["images"].numpy())
views = load_or_compute_sparse_depth(cache, inputs["key"], inputs["images"], inputs["intrinsics"], inputs["c2w"])
print("loaded", [len(v) for v in views], float(sum(v.depth.sum() for v in views)))
try:
    load_or_compute_sparse_depth(cache, inputs["key"], inputs["images"], inputs["intrinsics"], inputs["c2w"],
                                 percentile=(1.0, 99.0))
except SfMError as e:
    print("miss:", e)
"""


def test_cached_sparse_depth_loads_without_pycolmap(synthetic: dict, tmp_path: Path) -> None:
    """A machine without pycolmap (a GPU machine given the cache) reads a cached result; a cache miss there names the
    missing file and pycolmap instead of failing at import."""
    views, _ = synthetic[2]
    images = _uint8(views.images)
    key = {"scene": "synthetic", "views": [3, 5], "height": HEIGHT, "width": WIDTH}
    first = load_or_compute_sparse_depth(tmp_path / "cache", key, images, views.intrinsics, views.c2w)
    inputs = {"key": key, "images": torch.from_numpy(np.stack(images)), "intrinsics": views.intrinsics,
              "c2w": views.c2w}
    torch.save(inputs, tmp_path / "in.pt")
    result = subprocess.run([sys.executable, "-c", WITHOUT_PYCOLMAP, str(tmp_path / "cache"), str(tmp_path / "in.pt")],
                            capture_output=True, text=True, timeout=120, cwd=Path(__file__).parents[2])
    assert result.returncode == 0, result.stderr
    loaded, miss = result.stdout.splitlines()
    total = float(sum(v.depth.sum() for v in first))
    assert loaded.split(" ", 1)[0] == "loaded"
    assert loaded.split(" ", 1)[1] == f"{[len(v) for v in first]} {total}"
    assert miss.startswith("miss: sparse depth: no cached result ")
    assert "computing it (SfM) needs pycolmap, which is not installed: pip install pycolmap==4.2.1" in miss
    assert str(tmp_path / "cache" / "sparse_depth_") in miss


def test_fern_two_views_images_8_yield_points() -> None:
    fern = require_shared("data/nerf_llff_data/fern")
    scene = load_llff_scene(fern, factor=8, n_views=2)
    assert scene.split.train == [6, 13]
    views = subset(scene.views, scene.split.train)
    # Straight from the loader: float [0, 1] tensors.
    result = compute_sparse_depth(views.images, views.intrinsics, views.c2w)
    for index, view in enumerate(result):
        assert len(view) > 100, f"view {index}: only {len(view)} points"
        near, far = scene.bounds[scene.split.train[index]]
        # LLFF's bounds come from COLMAP's own points: ours must fall in roughly the same range.
        assert near * 0.9 < np.median(view.depth) < far * 1.1


def test_only_essential_matrix_poses_are_compared_with_the_given_poses():
    """A planar pair's relative pose comes from an ambiguous homography decomposition: no pose warning from it."""
    from types import SimpleNamespace

    from simplenerf.sfm.known_poses import MIN_POSE_INLIERS, PairReport, comparable, unchecked_reason

    config = pycolmap.TwoViewGeometryConfiguration
    pair = dict(cam2_from_cam1=pycolmap.Rigid3d(), inlier_matches=np.zeros((MIN_POSE_INLIERS, 2)))
    assert comparable(SimpleNamespace(config=config.CALIBRATED, **pair))
    assert comparable(SimpleNamespace(config=config.UNCALIBRATED, **pair))
    assert not comparable(SimpleNamespace(config=config.PLANAR, **pair))
    assert not comparable(SimpleNamespace(config=config.PLANAR_OR_PANORAMIC, **pair))
    assert not comparable(SimpleNamespace(config=config.CALIBRATED, cam2_from_cam1=None, inlier_matches=[]))
    # Too few matches for COLMAP's pose to judge the given one (horns' pair of 16 matches, 10.9 deg off): no warning.
    few = dict(cam2_from_cam1=pycolmap.Rigid3d(), inlier_matches=np.zeros((MIN_POSE_INLIERS - 1, 2)))
    assert not comparable(SimpleNamespace(config=config.CALIBRATED, **few))
    # The progress log says why such a pair's pose was not compared, so no warning does not read as "poses checked".
    reasons = [unchecked_reason(SimpleNamespace(config=config.CALIBRATED, **few)),
               unchecked_reason(SimpleNamespace(config=config.PLANAR, **pair)),
               unchecked_reason(SimpleNamespace(config=config.CALIBRATED, **pair))]
    assert reasons == [f"under {MIN_POSE_INLIERS} matches: too few to check the poses by",
                       "a planar pair: its pose is ambiguous, the poses are not checked by it", ""]
    few_report = PairReport((0, 1), MIN_POSE_INLIERS - 1, None, None, reasons[0])
    assert few_report.describe() == (f"views (0, 1): {MIN_POSE_INLIERS - 1} verified matches "
                                     f"(under {MIN_POSE_INLIERS} matches: too few to check the poses by)")
    assert not few_report.disagrees()
    assert PairReport((0, 1), 40, 1.3, 16.0).describe() == (
        "views (0, 1): 40 verified matches (rotation off 1.3 deg, baseline direction off 16 deg)")


def test_swapped_cameras_warn_that_the_images_disagree_with_the_poses(
    synthetic: dict, caplog: pytest.LogCaptureFixture
) -> None:
    views, _ = synthetic[2]
    swapped = views.c2w[[1, 0]].clone()
    # With swapped cameras triangulation may keep nothing (SfMError); the warning comes before it.
    with caplog.at_level("WARNING", logger="simplenerf.sfm.sparse_depth"), contextlib.suppress(SfMError):
        compute_sparse_depth(_uint8(views.images), views.intrinsics, swapped)
    warnings = [r.getMessage() for r in caplog.records if "disagree with the given poses" in r.getMessage()]
    assert len(warnings) == 1, caplog.text
    assert "views (0, 1)" in warnings[0]
    # The same cameras in their own order: no warning.
    caplog.clear()
    with caplog.at_level("WARNING", logger="simplenerf.sfm.sparse_depth"):
        compute_sparse_depth(_uint8(views.images), views.intrinsics, views.c2w)
    assert not [r for r in caplog.records if "disagree" in r.getMessage()], caplog.text
