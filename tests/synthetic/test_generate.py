"""Tests of the built-in synthetic scene: exact depth, LLFF layout, reprojection consistency and atomic writing."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from simplenerf.geometry.poses import poses_to_opengl
from simplenerf.metrics.scores import to_uint8
from simplenerf.synthetic import generate as sy

H, W = 48, 64  # small full resolution keeps the on-disk tests fast


@pytest.fixture(scope="module")
def scene() -> sy.SyntheticScene:
    return sy.build_scene(0, height=96, width=128, n_frames=20)


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "scene"
    return sy.make_synthetic_scene(root, height=H, width=W, n_frames=6, factors=(1, 2), seed=3)


def _d_cam(u: np.ndarray, v: np.ndarray, height: int, width: int, focal: float) -> np.ndarray:
    """The project's pixel convention, written out independently of the module: no +0.5, y up, looking along -z."""
    return np.stack([(u - width / 2) / focal, -(v - height / 2) / focal, -np.ones_like(u, dtype=np.float64)], -1)


def _c2w(rotation: np.ndarray, centre: tuple[float, float, float]) -> np.ndarray:
    return np.concatenate([rotation, np.asarray(centre, dtype=np.float64)[:, None]], axis=1)


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _reference_hit(scene: sy.SyntheticScene, origin: np.ndarray, direction: np.ndarray) -> tuple[float, int]:
    """Scalar ray tracer, one plane at a time, as a check on the vectorised one."""
    best_t, best_k = np.inf, -1
    for k, plane in enumerate(scene.planes):
        normal = np.cross(plane.axis_s, plane.axis_t)
        t = float(np.dot(plane.centre - origin, normal) / np.dot(direction, normal))
        if not 0.0 < t < best_t:
            continue
        local = origin + t * direction - plane.centre
        if abs(local @ plane.axis_s) <= plane.half_extent[0] and abs(local @ plane.axis_t) <= plane.half_extent[1]:
            best_t, best_k = t, k
    return best_t, best_k


def test_scene_is_deterministic_per_seed(scene: sy.SyntheticScene) -> None:
    again = sy.build_scene(0, height=96, width=128, n_frames=20)
    other = sy.build_scene(1, height=96, width=128, n_frames=20)
    np.testing.assert_array_equal(again.c2w, scene.c2w)
    rgb_a, depth_a = sy.render_view(scene, scene.c2w[4], 96, 128, scene.focal)
    rgb_b, depth_b = sy.render_view(again, again.c2w[4], 96, 128, again.focal)
    np.testing.assert_array_equal(rgb_a, rgb_b)
    np.testing.assert_array_equal(depth_a, depth_b)
    rgb_c, _ = sy.render_view(other, other.c2w[4], 96, 128, other.focal)
    assert np.abs(rgb_c - rgb_a).mean() > 0.05
    assert not np.allclose(other.c2w, scene.c2w)


def test_scene_layout_properties(scene: sy.SyntheticScene) -> None:
    assert scene.planes[0].name == "background" and not scene.planes[0].bounded
    assert all(p.bounded for p in scene.planes[1:])
    assert scene.focal == pytest.approx(64.0 / np.tan(np.radians(27.5)))  # 55 degree horizontal FOV
    rotations = scene.c2w[:, :, :3]
    np.testing.assert_allclose(
        rotations.transpose(0, 2, 1) @ rotations, np.broadcast_to(np.eye(3), (20, 3, 3)), 0, 1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-12)
    # Slight rotations only: every camera looks within a few degrees of -z (its back axis is near +z).
    assert np.all(rotations[:, 2, 2] > np.cos(np.radians(6.0)))
    centres = scene.c2w[:, :, 3]
    spread = centres.max(axis=0) - centres.min(axis=0)
    nearest = min(-p.centre[2] for p in scene.planes)
    assert 0.1 * nearest < spread[0] < 0.3 * nearest and spread[1] > 0.05 * nearest and spread[2] < 0.15
    for i in (0, 7, 19):
        _, idx, _ = sy.trace_view(scene, scene.c2w[i], 96, 128, scene.focal)
        assert set(np.unique(idx)) == set(range(len(scene.planes))), "every plane should be visible in every view"


def test_vectorised_tracer_matches_scalar_reference(scene: sy.SyntheticScene) -> None:
    rng = np.random.default_rng(0)
    for i in (2, 13):
        c2w = scene.c2w[i]
        depth, idx, _ = sy.trace_view(scene, c2w, 96, 128, scene.focal)
        for u, v in zip(rng.integers(0, 128, 60), rng.integers(0, 96, 60), strict=True):
            direction = c2w[:, :3] @ _d_cam(np.float64(u), np.float64(v), 96, 128, scene.focal)
            t_ref, k_ref = _reference_hit(scene, c2w[:, 3], direction)
            assert idx[v, u] == k_ref
            assert depth[v, u] == pytest.approx(t_ref, abs=1e-12)
        # The general tracer on the same rays (as `pixel_rays` builds them) agrees with the per-view one.
        origin, directions = sy.pixel_rays(c2w, 96, 128, scene.focal)
        t_gen, idx_gen, st_gen = sy.trace_rays(scene, origin, directions)
        np.testing.assert_array_equal(idx_gen, idx)
        np.testing.assert_allclose(t_gen, depth, rtol=0, atol=1e-12)
        np.testing.assert_allclose(st_gen, sy.trace_view(scene, c2w, 96, 128, scene.focal)[2], rtol=0, atol=1e-12)


def test_background_depth_is_analytic(scene: sy.SyntheticScene) -> None:
    z_bg = scene.planes[0].centre[2]
    # Far to the side of every bounded rectangle, only the background can be hit.
    ident = sy.trace_view(scene, _c2w(np.eye(3), (100.0, 3.0, 0.25)), 96, 128, scene.focal)
    assert np.all(ident[1] == 0)
    np.testing.assert_allclose(ident[0], 0.25 - z_bg, rtol=0, atol=1e-12)
    c2w = _c2w(_rot_y(0.08) @ _rot_z(0.05), (100.0, -2.0, 0.4))
    depth, idx, _ = sy.trace_view(scene, c2w, 96, 128, scene.focal)
    uu, vv = np.meshgrid(np.arange(128.0), np.arange(96.0))
    d_world = _d_cam(uu, vv, 96, 128, scene.focal) @ c2w[:, :3].T
    assert np.all(idx == 0)
    np.testing.assert_allclose(depth, (z_bg - 0.4) / d_world[..., 2], rtol=0, atol=1e-5)
    # Background pixels of a real (rotated) scene view obey the same formula.
    c2w = scene.c2w[11]
    _, depth = sy.render_view(scene, c2w, 96, 128, scene.focal)
    _, idx, _ = sy.trace_view(scene, c2w, 96, 128, scene.focal)
    d_world = _d_cam(uu, vv, 96, 128, scene.focal) @ c2w[:, :3].T
    background = idx == 0
    assert background.mean() > 0.2
    expected = (z_bg - c2w[2, 3]) / d_world[..., 2]
    np.testing.assert_allclose(depth[background], expected[background], rtol=0, atol=1e-5)
    assert np.all(depth[~background] < expected[~background]), "occluders must lie in front of the background"


def test_principal_point_depth_with_identity_rotation(scene: sy.SyntheticScene) -> None:
    near_rect = min(scene.planes[1:], key=lambda p: -p.centre[2])
    assert near_rect.axis_s @ [1, 0, 0] == 1.0 and near_rect.axis_t @ [0, 1, 0] == 1.0
    for dx, dy, cam_z in [(0.0, 0.0, 0.0), (0.2, -0.1, 0.3), (-0.3, 0.25, -0.2)]:
        centre = (near_rect.centre[0] + dx, near_rect.centre[1] + dy, cam_z)
        for height, width in [(96, 128), (378, 504)]:
            focal = scene.focal * width / 128
            depth, idx, _ = sy.trace_view(scene, _c2w(np.eye(3), centre), height, width, focal)
            assert depth[height // 2, width // 2] == pytest.approx(-(near_rect.centre[2] - cam_z), abs=1e-12)
            assert scene.planes[idx[height // 2, width // 2]] is near_rect


def test_reprojection_consistency_and_occlusions(scene: sy.SyntheticScene) -> None:
    """A pixel's exact 3D point, seen from another view, has exactly that view's depth unless something occludes it.

    On a plane the inverse z-depth is affine in (u, v), so bilinear interpolation of 1 / depth between four pixels
    of the same plane is exact at any sub-pixel position.
    """
    h, w, f = 96, 128, scene.focal
    for a, b in [(0, 19), (7, 12), (10, 3)]:
        depth_a, idx_a, _ = sy.trace_view(scene, scene.c2w[a], h, w, f)
        depth_b, idx_b, _ = sy.trace_view(scene, scene.c2w[b], h, w, f)
        uu, vv = np.meshgrid(np.arange(float(w)), np.arange(float(h)))
        points = scene.c2w[a][:, 3] + depth_a[..., None] * (_d_cam(uu, vv, h, w, f) @ scene.c2w[a][:, :3].T)
        p_cam = (points - scene.c2w[b][:, 3]) @ scene.c2w[b][:, :3]  # R^T (X - o)
        z_b = -p_cam[..., 2]
        u_b, v_b = w / 2 + f * p_cam[..., 0] / z_b, h / 2 - f * p_cam[..., 1] / z_b
        inside = (u_b >= 0) & (u_b < w - 1) & (v_b >= 0) & (v_b < h - 1)
        u0 = np.clip(np.floor(u_b), 0, w - 2).astype(int)
        v0 = np.clip(np.floor(v_b), 0, h - 2).astype(int)
        corners = [(v0, u0), (v0, u0 + 1), (v0 + 1, u0), (v0 + 1, u0 + 1)]
        first = idx_b[corners[0]]
        one_plane = inside & np.all([idx_b[c] == first for c in corners], axis=0)
        fu, fv = u_b - u0, v_b - v0
        weights = [(1 - fv) * (1 - fu), (1 - fv) * fu, fv * (1 - fu), fv * fu]
        inv_depth_b = sum(wt / depth_b[c] for wt, c in zip(weights, corners, strict=True))
        visible = one_plane & (first == idx_a)
        assert visible.mean() > 0.5
        np.testing.assert_allclose(inv_depth_b[visible], 1.0 / z_b[visible], rtol=1e-9, atol=0)
        # Where B sees another plane there, that plane must be in front of the point: the point is occluded in B.
        other = one_plane & (first != idx_a)
        assert np.all(inv_depth_b[other] > 1.0 / z_b[other] + 1e-6)
        assert other.sum() > 20, "some pixels of A should be occluded in B (parallax at depth edges)"


def test_views_differ_and_textures_are_feature_rich(scene: sy.SyntheticScene) -> None:
    rgb0, _ = sy.render_view(scene, scene.c2w[0], 96, 128, scene.focal)
    rgb1, _ = sy.render_view(scene, scene.c2w[1], 96, 128, scene.focal)
    assert rgb0.shape == (96, 128, 3) and 0.0 < rgb0.min() and rgb0.max() < 1.0
    assert np.abs(rgb0 - rgb1).mean() > 0.05
    assert rgb0.reshape(-1, 3).std(axis=0).min() > 0.1
    rgb, _ = sy.render_view(scene, scene.c2w[5], 378, 504, scene.focal * 504 / 128)
    gray = cv2.cvtColor(to_uint8(rgb), cv2.COLOR_RGB2GRAY)
    assert len(cv2.SIFT_create().detect(gray, None)) > 300


def test_written_layout(written: Path) -> None:
    poses_bounds = np.load(written / "poses_bounds.npy")
    assert poses_bounds.shape == (6, 17) and poses_bounds.dtype == np.float64
    for factor, images, depths in [(1, "images", "depths"), (2, "images_2", "depths_2")]:
        names = sorted(p.name for p in (written / images).iterdir())
        assert names == [f"{i:03d}.png" for i in range(6)]
        for i in range(6):
            bgr = cv2.imread(str(written / images / f"{i:03d}.png"), cv2.IMREAD_UNCHANGED)
            assert bgr.shape == (H // factor, W // factor, 3) and bgr.dtype == np.uint8
            depth = np.load(written / depths / f"{i:03d}.npy")
            assert depth.shape == (H // factor, W // factor) and depth.dtype == np.float32
    meta = json.loads((written / "scene.json").read_text())
    assert meta["seed"] == 3 and meta["factors"] == [1, 2] and meta["n_frames"] == 6
    assert [p["name"] for p in meta["planes"]][0] == "background"
    assert not list(written.parent.glob(".*tmp*"))


def test_written_images_and_depths_match_rendering(written: Path) -> None:
    scene = sy.build_scene(3, height=H, width=W, n_frames=6)
    for i in (0, 5):
        rgb, depth = sy.render_view(scene, scene.c2w[i], H, W, scene.focal)
        bgr = cv2.imread(str(written / "images" / f"{i:03d}.png"))
        np.testing.assert_array_equal(bgr[..., ::-1], to_uint8(rgb))  # stored as BGR
        np.testing.assert_array_equal(np.load(written / "depths" / f"{i:03d}.npy"), depth.astype(np.float32))


def test_poses_bounds_round_trip(written: Path) -> None:
    scene = sy.build_scene(3, height=H, width=W, n_frames=6)
    poses_bounds = np.load(written / "poses_bounds.npy")
    mats = poses_bounds[:, :15].reshape(-1, 3, 5)
    down, right, back, centre, hwf = (mats[:, :, k] for k in range(5))
    c2w = np.stack([right, -down, back, centre], axis=-1)  # LLFF [down, right, back] -> OpenGL [right, up, back]
    np.testing.assert_array_equal(c2w, scene.c2w)
    np.testing.assert_array_equal(hwf, np.broadcast_to([H, W, scene.focal], (6, 3)))
    c2w_fn, hwf_fn, bounds_fn = poses_to_opengl(poses_bounds)
    np.testing.assert_array_equal(c2w_fn, scene.c2w)
    np.testing.assert_array_equal(hwf_fn, hwf)
    for i in range(6):
        full = np.load(written / "depths" / f"{i:03d}.npy")
        half = np.load(written / "depths_2" / f"{i:03d}.npy")
        assert poses_bounds[i, 15] == float(full.min()) and poses_bounds[i, 16] == float(full.max())
        np.testing.assert_array_equal(bounds_fn[i], [full.min(), full.max()])
        assert poses_bounds[i, 15] <= half.min() and half.max() <= poses_bounds[i, 16]


def test_factor_two_is_the_even_pixel_subgrid(written: Path) -> None:
    """With the no-+0.5 convention, f / 2 and cx = W / 4 make pixel (u, v) at factor 2 the ray of (2u, 2v)."""
    for i in range(6):
        full_depth = np.load(written / "depths" / f"{i:03d}.npy")
        half_depth = np.load(written / "depths_2" / f"{i:03d}.npy")
        np.testing.assert_allclose(half_depth, full_depth[::2, ::2], rtol=1e-6, atol=0)
        full = cv2.imread(str(written / "images" / f"{i:03d}.png")).astype(int)
        half = cv2.imread(str(written / "images_2" / f"{i:03d}.png")).astype(int)
        assert np.abs(half - full[::2, ::2]).max() <= 1  # float rounding may flip an 8-bit level


def test_make_is_deterministic_and_seed_dependent(tmp_path: Path, written: Path) -> None:
    again = sy.make_synthetic_scene(tmp_path / "a", height=H, width=W, n_frames=6, factors=(2, 1), seed=3)
    files = sorted(p.relative_to(written) for p in written.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (written / rel).read_bytes() == (again / rel).read_bytes(), rel
    other = sy.make_synthetic_scene(tmp_path / "b", height=H, width=W, n_frames=6, seed=4)
    assert (other / "images" / "000.png").read_bytes() != (written / "images" / "000.png").read_bytes()
    assert not np.array_equal(np.load(other / "poses_bounds.npy"), np.load(written / "poses_bounds.npy"))


def test_make_is_idempotent_and_protects_other_scenes(tmp_path: Path) -> None:
    root = tmp_path / "scene"
    sy.make_synthetic_scene(root, height=H, width=W, n_frames=3, factors=(2,))
    assert not (root / "images").exists()
    stamp = (root / "scene.json").stat().st_mtime_ns
    assert sy.make_synthetic_scene(str(root), height=H, width=W, n_frames=3, factors=(2,)) == root
    assert (root / "scene.json").stat().st_mtime_ns == stamp
    # Asking for a missing factor rebuilds with the union; the existing factor's bytes are unchanged.
    before = (root / "images_2" / "001.png").read_bytes()
    sy.make_synthetic_scene(root, height=H, width=W, n_frames=3, factors=(1,))
    assert json.loads((root / "scene.json").read_text())["factors"] == [1, 2]
    assert (root / "images_2" / "001.png").read_bytes() == before
    with pytest.raises(FileExistsError):
        sy.make_synthetic_scene(root, height=H, width=W, n_frames=3, seed=1)
    sy.make_synthetic_scene(root, height=H, width=W, n_frames=3, seed=1, overwrite=True)
    assert json.loads((root / "scene.json").read_text())["seed"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_failed_write_leaves_nothing_behind(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def crash(scene: sy.SyntheticScene, out: Path, factors: list[int]) -> None:
        (out / "images").mkdir()
        (out / "images" / "000.png").write_bytes(b"partial")
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(sy, "_write_scene", crash)
    with pytest.raises(RuntimeError, match="simulated crash"):
        sy.make_synthetic_scene(tmp_path / "scene", height=H, width=W, n_frames=2)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("factors", [(3,), (1, 5), (0,)])
def test_factor_must_divide_resolution(tmp_path: Path, factors: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="divisible|positive"):
        sy.make_synthetic_scene(tmp_path / "scene", height=H, width=W, factors=factors)
    assert not (tmp_path / "scene").exists()


def test_command_line_entry(tmp_path: Path, capsys) -> None:
    from simplenerf.commands import main

    main(["synthetic", str(tmp_path / "cli"), "--height", "24", "--width", "32", "--n_frames", "2", "--factors", "1",
          "2"])
    assert capsys.readouterr().out == f"{tmp_path / 'cli'}\n"
    assert (tmp_path / "cli" / "images_2" / "001.png").is_file()
    assert np.load(tmp_path / "cli" / "poses_bounds.npy").shape == (2, 17)


def test_an_objects_scene_records_the_opencv_that_drew_it(tmp_path: Path) -> None:
    """The objects kind's pictures depend on OpenCV's drawing; scene.json says which version drew them, and one
    install draws the same scene twice."""
    first = sy.make_synthetic_scene(tmp_path / "a", height=H, width=W, n_frames=6, kind="objects")
    second = sy.make_synthetic_scene(tmp_path / "b", height=H, width=W, n_frames=6, kind="objects")
    assert json.loads((first / "scene.json").read_text())["drawn_with"] == f"OpenCV {cv2.__version__}"
    for i in range(6):
        name = f"images/{i:03d}.png"
        assert (first / name).read_bytes() == (second / name).read_bytes()
    planes = sy.make_synthetic_scene(tmp_path / "c", height=H, width=W, n_frames=6)
    assert "drawn_with" not in json.loads((planes / "scene.json").read_text())
