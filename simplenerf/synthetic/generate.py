"""The built-in synthetic scene: a deterministic, analytically ray-traced forward-facing scene in the LLFF layout.

The scene is the project's embedded default data (used by the CPU demo) and the ground truth of the exact depth,
reprojection and mask tests, so every pixel is defined by a single analytic ray-plane intersection:

- World axes are OpenGL-style (x right, y up, z backwards; cameras look along -z).
- Two kinds of scene (`build_scene(kind=...)`), both made of planes only:
  - "planes" (the default, pinned by the tests): an infinite textured background plane at z = -10, three bounded
    fronto-parallel rectangles at z of about -7, -5 and -3.2 and one bounded slanted rectangle at about z = -6,
    placed so that they partially occlude each other and the background. Textures are smooth, band-limited
    procedural patterns (sums of random sinusoids plus a soft checker, squashed by tanh) in each plane's own 2D
    coordinates, with wavelengths proportional to the plane's depth so that they look alike on screen, carry many
    SIFT keypoints and do not alias at low resolution.
  - "objects" (the grid demo's): a scene a person recognises, with pictures drawn by cv2 (`ImageTexture`): a wall at
    z = -10 with wooden panelling, a poster ("NeRF", mountains), text ("SimpleNeRF") and a clock; a checkered floor
    receding from z = -3.2 to -10; a dice (three faces: a box) at about z = -6; a calibration checkerboard turned
    25 degrees at z = -3.6; a round dartboard at z = -5; a hazard-striped "STOP" sign at z = -8.5 and a slanted
    poster ("3D", colour bars) at z = -7.8. Large plain areas (wall, dice faces) next to textured ones are where
    few-view depth is ambiguous.
- Cameras: "planes": a jittered grid of centres in the x-y plane near z = 0 (baseline ~0.6, about 19% of the nearest
  depth); "objects": a handheld-like left-to-right sweep (x from -0.3 to 0.3, a +-0.06 vertical wave). Each camera
  looks at the scene centre (0, 0, -6) with a small random roll.
- Pixel (u, v) (u = column, v = row) is the ray through the integer image coordinate (u, v), no +0.5, with
  camera-frame direction [(u - cx) / f, -(v - cy) / f, -1], cx = W / 2, cy = H / 2, exactly as in
  `geometry.rays`. Its colour is the texture at the first hit (point-sampled) and its depth is the camera z-depth
  of that same hit, i.e. the ray parameter t, so depth maps are exact for the very rays that made the colours.
  A consequence of this convention: pixel (u, v) at factor k is the ray of full-resolution pixel (k u, k v).

On disk (`make_synthetic_scene`), the layout is LLFF's `nerf_llff_data/<scene>/`: `images/` (factor 1) or
`images_{k}/` with `{i:03d}.png`, exact float32 depth maps in `depths/` or `depths_{k}/` as `{i:03d}.npy`,
`poses_bounds.npy` ([N, 17] float64, LLFF rotation columns [down, right, back], hwf of the full resolution, near/far
= min/max of the full-resolution exact depth of the view) and a human-readable `scene.json`.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from simplenerf.geometry.poses import to_poses_bounds
from simplenerf.metrics.scores import to_uint8
from simplenerf.synthetic.objects import _objects
from simplenerf.synthetic.scene import (
    FORMAT_VERSION,
    HFOV_DEGREES,
    SCENE_CENTRE,
    SCENE_KINDS,
    SyntheticScene,
    _camera_centres,
    _check_factor,
    _look_at,
    _noise_planes,
    _sweep_centres,
)


def build_scene(
    seed: int = 0, *, height: int = 96, width: int = 128, n_frames: int = 20, kind: str = "planes"
) -> SyntheticScene:
    """The scene description (no rendering). Everything random comes from `np.random.default_rng(seed)`.

    `kind`: "planes" (the default: colour-noise textures on five planes, what the tests pin) or "objects" (pictures a
    person recognises: a wall with a poster, text and a clock, a checkered floor, a dice, a calibration board, a
    dartboard, a sign and a slanted poster; the seed moves only the cameras, which sweep from left to right).
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    if height < 1 or width < 1:
        raise ValueError(f"height and width must be positive, got {height}x{width}")
    if kind not in SCENE_KINDS:
        raise ValueError(f"kind must be one of {SCENE_KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    planes = _noise_planes(rng) if kind == "planes" else _objects()
    centres = _camera_centres(rng, n_frames) if kind == "planes" else _sweep_centres(rng, n_frames)
    rolls = np.radians(rng.uniform(-1.5, 1.5, n_frames))
    target = np.asarray(SCENE_CENTRE)
    c2w = np.stack([_look_at(c, target, float(r)) for c, r in zip(centres, rolls, strict=True)])
    focal = 0.5 * width / math.tan(0.5 * math.radians(HFOV_DEGREES))
    return SyntheticScene(seed=seed, height=height, width=width, focal=focal, planes=planes, c2w=c2w, kind=kind)


def pixel_rays(c2w: np.ndarray, height: int, width: int, focal: float) -> tuple[np.ndarray, np.ndarray]:
    """Rays of all pixels of an image, in this project's convention (module docstring).

    Returns:
        origin [3] and directions [H, W, 3] (un-normalised, camera-frame z = -1, so t along them is z-depth).
    """
    u = np.arange(width, dtype=np.float64)
    v = np.arange(height, dtype=np.float64)
    uu, vv = np.meshgrid(u, v)
    d_cam = np.stack([(uu - width / 2) / focal, -(vv - height / 2) / focal, -np.ones_like(uu)], axis=-1)
    c2w = np.asarray(c2w, dtype=np.float64)
    return c2w[:3, 3].copy(), d_cam @ c2w[:3, :3].T


ProjectFn = Callable[[np.ndarray], np.ndarray | float]


def _first_hits(
    scene: SyntheticScene, shape: tuple[int, ...], dot_dir: ProjectFn, dot_origin: ProjectFn
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest plane hit of every ray, given how to dot a world vector with the ray directions and with the origins.

    Returns t, plane index (-1: no hit) and the hit's plane coordinates s, t, each of `shape`.
    """
    best_t = np.full(shape, np.inf)
    best_idx = np.full(shape, -1, dtype=np.int64)
    best_s, best_tc = np.zeros(shape), np.zeros(shape)
    for idx, plane in enumerate(scene.planes):
        denom = dot_dir(plane.normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.broadcast_to((plane.normal @ plane.centre - dot_origin(plane.normal)) / denom, shape)
        # Strict t > 0 keeps hits in front of the camera; the denominator check drops rays parallel to the plane.
        hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (t < best_t)
        s_coord = dot_origin(plane.axis_s) - plane.axis_s @ plane.centre + t * dot_dir(plane.axis_s)
        t_coord = dot_origin(plane.axis_t) - plane.axis_t @ plane.centre + t * dot_dir(plane.axis_t)
        if plane.round:
            hit &= (s_coord / plane.half_extent[0]) ** 2 + (t_coord / plane.half_extent[1]) ** 2 <= 1.0
        elif plane.bounded:
            hit &= (np.abs(s_coord) <= plane.half_extent[0]) & (np.abs(t_coord) <= plane.half_extent[1])
        np.copyto(best_t, t, where=hit)
        np.copyto(best_idx, idx, where=hit)
        np.copyto(best_s, s_coord, where=hit)
        np.copyto(best_tc, t_coord, where=hit)
    return best_t, best_idx, best_s, best_tc


def trace_rays(
    scene: SyntheticScene, origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First plane hit along arbitrary rays o + t d.

    Args:
        origins: [..., 3] (or anything broadcastable to directions, e.g. one shared [3]). directions: [..., 3], any
            length.

    Returns:
        t [...] (inf where nothing is hit), plane index [...] (-1 where nothing is hit) and the plane coordinates
        st [..., 2] of the hit in the hit plane's (axis_s, axis_t) frame.
    """
    directions = np.asarray(directions, dtype=np.float64)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
    shape = directions.shape[:-1]
    depth, idx, s_coord, t_coord = _first_hits(scene, shape, lambda vec: directions @ vec, lambda vec: origins @ vec)
    return depth, idx, np.stack([s_coord, t_coord], axis=-1)


def _trace_view(
    scene: SyntheticScene, c2w: np.ndarray, height: int, width: int, focal: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    c2w = np.asarray(c2w, dtype=np.float64)
    rotation, origin = c2w[:3, :3], c2w[:3, 3]
    x_cam = (np.arange(width, dtype=np.float64) - width / 2) / focal  # [W]
    y_cam = -(np.arange(height, dtype=np.float64) - height / 2) / focal  # [H]

    # vec . (R d_cam) = (R^T vec) . d_cam is a row term plus a column term, so each per-plane product over the
    # whole image is one broadcast add instead of a [H, W, 3] contraction (the tracing cost drops ~5x).
    def dot_dir(vec: np.ndarray) -> np.ndarray:
        g = rotation.T @ vec
        return (g[0] * x_cam)[None, :] + (g[1] * y_cam - g[2])[:, None]

    def dot_origin(vec: np.ndarray) -> float:
        return float(origin @ vec)

    depth, idx, s_coord, t_coord = _first_hits(scene, (height, width), dot_dir, dot_origin)
    if np.any(idx < 0):
        raise RuntimeError("some rays miss the background plane; the camera must look along -z")
    return depth, idx, s_coord, t_coord


def trace_view(
    scene: SyntheticScene, c2w: np.ndarray, height: int, width: int, focal: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel (depth [H, W] float64, plane index [H, W] int64, plane coordinates [H, W, 2]) of one view.

    Same rays as `pixel_rays` (principal point (width / 2, height / 2)); agrees with `trace_rays` on them up to
    float64 rounding.
    """
    depth, idx, s_coord, t_coord = _trace_view(scene, c2w, height, width, focal)
    return depth, idx, np.stack([s_coord, t_coord], axis=-1)


def render_view(
    scene: SyntheticScene, c2w: np.ndarray, height: int, width: int, focal: float
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic rendering of one view with principal point (width / 2, height / 2).

    Returns:
        rgb [H, W, 3] float32 in (0, 1) (texture of the first hit, point-sampled) and depth [H, W] float64 (camera
        z-depth of that same hit).
    """
    depth, idx, s_coord, t_coord = _trace_view(scene, c2w, height, width, focal)
    rgb = np.zeros((3, height, width), dtype=np.float32)
    for k, plane in enumerate(scene.planes):
        mask = idx == k
        if mask.any():
            rgb[:, mask] = plane.texture.channels_first(s_coord[mask], t_coord[mask])
    return np.ascontiguousarray(rgb.transpose(1, 2, 0)), depth


def _subdir(kind: str, factor: int) -> str:
    return kind if factor == 1 else f"{kind}_{factor}"


def _key(meta: dict[str, object]) -> tuple[object, ...]:
    # Scenes written before there were kinds are "planes" scenes.
    kind = meta.get("kind", "planes")
    return (*(meta.get(k) for k in ("format_version", "seed", "height", "width", "n_frames")), kind)


def _read_meta(root: Path) -> dict[str, object] | None:
    try:
        return json.loads((root / "scene.json").read_text())
    except (OSError, ValueError):
        return None


def _write_scene(scene: SyntheticScene, out: Path, factors: Sequence[int]) -> None:
    n = scene.n_frames
    near, far = np.empty(n), np.empty(n)
    for k in sorted(set(factors)):
        (out / _subdir("images", k)).mkdir()
        (out / _subdir("depths", k)).mkdir()
    for i in range(n):
        for k in sorted(set(factors) | {1}):
            h, w, f = scene.intrinsics(k)
            if k in factors:
                rgb, depth = render_view(scene, scene.c2w[i], h, w, f)
                path = out / _subdir("images", k) / f"{i:03d}.png"
                if not cv2.imwrite(str(path), cv2.cvtColor(to_uint8(rgb), cv2.COLOR_RGB2BGR)):
                    raise OSError(f"cv2 failed to write {path}")
                np.save(out / _subdir("depths", k) / f"{i:03d}.npy", depth.astype(np.float32))
            else:
                # The bounds always come from the full resolution so poses_bounds.npy does not depend on `factors`.
                depth = trace_view(scene, scene.c2w[i], h, w, f)[0]
            if k == 1:
                # Every factor's pixel grid is a subset of the full-resolution one, so these bound all stored depths.
                depth32 = depth.astype(np.float32)
                near[i], far[i] = float(depth32.min()), float(depth32.max())
    hwf = np.broadcast_to(np.array([scene.height, scene.width, scene.focal], dtype=np.float64), (n, 3))
    np.save(out / "poses_bounds.npy", to_poses_bounds(scene.c2w, hwf, np.stack([near, far], axis=1)))
    meta = {
        "format_version": FORMAT_VERSION,
        "seed": scene.seed,
        "kind": scene.kind,
        "height": scene.height,
        "width": scene.width,
        "n_frames": n,
        "factors": sorted(set(factors)),
        "focal": scene.focal,
        "hfov_degrees": HFOV_DEGREES,
        "conventions": (
            "OpenGL world/camera axes; pixel (u, v) ray direction [(u-cx)/f, -(v-cy)/f, -1] with cx=W/2, cy=H/2 "
            "(no +0.5); depth = camera z-depth of the first hit; poses_bounds.npy rotation columns [down, right, back]"
        ),
        "planes": [p.describe() for p in scene.planes],
        "camera_centres": scene.c2w[:, :, 3].tolist(),
    }
    if scene.kind == "objects":
        # Its pictures are drawn by cv2, whose anti-aliased lines and text differ between OpenCV versions (4.14, 5.0
        # and 5.1 give different images, and so different demo scores; `make setup` pins the version).
        meta["drawn_with"] = f"OpenCV {cv2.__version__}"
    (out / "scene.json").write_text(json.dumps(meta, indent=2))


def make_synthetic_scene(
    root: str | Path,
    *,
    height: int = 96,
    width: int = 128,
    n_frames: int = 20,
    factors: Sequence[int] = (1,),
    seed: int = 0,
    overwrite: bool = False,
    kind: str = "planes",
) -> Path:
    """Writes the synthetic scene to `root` in the LLFF layout (module docstring) and returns `root`.

    `height`/`width` are the full resolution and must be divisible by every factor. `kind`: see `build_scene`. If
    `root` already holds this scene (same kind, seed, size, frame count and format version) with all requested
    factors, nothing is done; if it lacks some factors it is rebuilt with the union of the factors. A different
    scene at `root` raises FileExistsError unless `overwrite`. The scene is built in a temporary directory next to
    `root` and renamed into place, so a crash never leaves a half-written scene.
    """
    root = Path(root)
    factors = sorted({int(k) for k in factors})
    if not factors:
        raise ValueError("factors must not be empty")
    for k in factors:
        _check_factor(height, width, k)
    wanted = {"format_version": FORMAT_VERSION, "seed": seed, "height": height, "width": width, "n_frames": n_frames,
              "kind": kind}
    if root.exists():
        meta = _read_meta(root)
        if meta is not None and _key(meta) == _key(wanted):
            existing = {int(k) for k in meta.get("factors", [])}
            if set(factors) <= existing:
                return root
            # Same scene, more factors: regenerate with the union (identical content for the existing factors).
            factors = sorted(existing | set(factors))
        elif not overwrite:
            raise FileExistsError(f"{root} exists and does not hold this synthetic scene; pass overwrite=True")
    scene = build_scene(seed, height=height, width=width, n_frames=n_frames, kind=kind)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.tmp-", dir=root.parent))
    try:
        _write_scene(scene, tmp, factors)
        if root.exists():
            # Move the old scene aside first: rename cannot replace a non-empty directory.
            trash = Path(tempfile.mkdtemp(prefix=f".{root.name}.old-", dir=root.parent))
            os.replace(root, trash / "scene")
            shutil.rmtree(trash, ignore_errors=True)
        try:
            os.rename(tmp, root)
        except OSError:
            # A concurrent writer may have won the race; its scene is just as good if the parameters match.
            meta = _read_meta(root)
            if meta is None or _key(meta) != _key(wanted) or not set(factors) <= set(meta.get("factors", [])):
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return root
