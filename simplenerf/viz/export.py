"""The learned geometry of a trained NeRF as files: each view's depth map and one coloured point cloud.

For every exported view (the train views by default) the fine network renders the full frame deterministically
(`NeRF.render_rays_chunked`, as the test renders): `depth/<name>.npy` (float32 [H, W] camera z-depth) and
`depth/<name>.png` (colourised inverse depth). The pixels whose accumulated opacity exceeds a threshold (and whose
depth is below a limit, which drops the "infinitely far" background of NDC scenes) are lifted to 3D along their
rays, point = origin + depth * direction (directions have camera z = -1, so t is the z-depth), coloured by the
photo, and fused into `points.ply` (binary little-endian PLY: float x, y, z and uchar red, green, blue per vertex,
which MeshLab, CloudCompare and Open3D read). `export.json` records the views, their cameras and the counts.

Units and frame: those of the model, i.e. the data module's scene (scaled by `scene.scale` and recentred on the
average train pose): depth in the scene's file units (as `poses_bounds.npy`) is depth / scale.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from simplenerf.geometry.rays import pixel_grid, pixel_rays
from simplenerf.geometry.views import Views
from simplenerf.viz.pictures import colorize_depth, to_uint8, write_png
from simplenerf.viz.video import frame_rays

PLY_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


@dataclass
class RenderedView:
    """What the model renders for one view."""

    depth: np.ndarray  # [H, W] float32, camera z-depth in scene units
    accumulation: np.ndarray  # [H, W] float32, accumulated opacity in [0, 1]
    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]


@torch.no_grad()
def render_view(nerf: nn.Module, c2w: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int, near: float,
                chunk: int) -> RenderedView:
    """Renders every pixel of one camera with the fine network, deterministically.

    Args:
        nerf: a `simplenerf.model.nerf.NeRF` (anything with its `render_rays_chunked`); rays are built in the dtype
            and on the device of its parameters, and it is put in eval mode for the render.
        c2w: [3, 4] camera-to-world, OpenGL axes.
        intrinsics: [3, 3] of this height x width.
        height: image height in pixels.
        width: image width in pixels.
        near: NDC near plane (the data module's `near`).
        chunk: rays per forward pass.
    """
    param = next(nerf.parameters())
    rays = frame_rays(c2w.to(param.device, param.dtype), intrinsics.to(param.device, param.dtype), height, width, near)
    was_training = nerf.training
    nerf.eval()
    try:
        out = nerf.render_rays_chunked(rays, chunk)
    finally:
        nerf.train(was_training)
    return RenderedView(
        depth=out.depth.reshape(height, width).float().cpu().numpy(),
        accumulation=out.accumulation.reshape(height, width).float().cpu().numpy(),
        rgb=out.rgb.reshape(height, width, 3).float().cpu().numpy(),
    )


def lift_pixels(depth: np.ndarray, keep: np.ndarray, intrinsics: torch.Tensor, c2w: torch.Tensor) -> np.ndarray:
    """World points [P, 3] (float64) of the kept pixels of one view, row-major: origin + depth x direction.

    Args:
        depth: [H, W] camera z-depth.
        keep: [H, W] bool, the pixels to lift.
        intrinsics: [3, 3] of the view.
        c2w: [3, 4] of the view, OpenGL axes.
    """
    height, width = depth.shape
    uv = pixel_grid(height, width)[torch.from_numpy(keep.reshape(-1))]
    k, pose = intrinsics.detach().cpu().double(), c2w.detach().cpu().double()
    origins, directions = pixel_rays(k[None], pose[None], uv)
    t = torch.from_numpy(depth.reshape(-1)[keep.reshape(-1)].astype(np.float64))
    return (origins + t[:, None] * directions).numpy()


def write_ply(path: str | Path, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    """Writes a coloured point cloud as a binary little-endian PLY (written to a temporary file, then renamed).

    Args:
        path: the .ply to write (its folder must exist).
        xyz: [P, 3] positions (stored as float32).
        rgb: [P, 3] uint8 colours.
    """
    xyz, rgb = np.asarray(xyz), np.asarray(rgb)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape or rgb.dtype != np.uint8:
        raise ValueError(f"need xyz [P, 3] and uint8 rgb [P, 3], got {xyz.shape} and {rgb.shape} {rgb.dtype}")
    vertices = np.empty(len(xyz), dtype=PLY_VERTEX)
    for axis, name in enumerate("xyz"):
        vertices[name] = xyz[:, axis]
    for channel, name in enumerate(("red", "green", "blue")):
        vertices[name] = rgb[:, channel]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment simplenerf: fused NeRF depth of the train views\n"
        f"element vertex {len(vertices)}\n"
        + "".join(f"property {kind} {name}\n" for name, kind in (("x", "float"), ("y", "float"), ("z", "float"),
                                                                  ("red", "uchar"), ("green", "uchar"),
                                                                  ("blue", "uchar")))
        + "end_header\n"
    )
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(vertices.tobytes())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp's file is private; give it a normal file's permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def export_geometry(
    nerf: nn.Module,
    views: Views,
    near: float,
    chunk: int,
    out_dir: str | Path,
    *,
    min_accumulation: float = 0.9,
    max_depth: Sequence[float] | float | None = None,
    stride: int = 1,
    scale: float = 1.0,
) -> dict:
    """Renders the depth of each view, writes its depth files, and fuses the kept pixels into `points.ply`.

    Args:
        nerf: the trained `NeRF`, on any device.
        views: the views to export (their images colour the points; names name the files).
        near: NDC near plane of the data module.
        chunk: rays per forward pass.
        out_dir: output folder (created; files of the same names are replaced).
        min_accumulation: keep pixels whose accumulated opacity is above this for the point cloud.
        max_depth: keep pixels at most this deep (scene units): one value, one per view, or None (no limit).
        stride: use every stride-th pixel in each direction for the point cloud (depth maps stay full size).
        scale: the scene's scale (scene units per file unit), recorded in export.json.

    Returns:
        The summary written to export.json.
    """
    if stride < 1:
        raise ValueError(f"stride must be at least 1, got {stride}")
    limits = [None] * len(views) if max_depth is None else list(np.broadcast_to(np.asarray(max_depth, float),
                                                                                 (len(views),)))
    out_dir = Path(out_dir)
    (out_dir / "depth").mkdir(parents=True, exist_ok=True)
    points, colours, per_view = [], [], []
    for i in tqdm(range(len(views)), desc="rendering depth", unit="view"):
        name = views.names[i]
        rendered = render_view(nerf, views.c2w[i], views.intrinsics[i], views.height, views.width, near, chunk)
        np.save(out_dir / "depth" / f"{name}.npy", rendered.depth.astype(np.float32))
        write_png(out_dir / "depth" / f"{name}.png", colorize_depth(rendered.depth))
        opaque = rendered.accumulation > min_accumulation
        near_enough = np.isfinite(rendered.depth) & (rendered.depth > 0)
        if limits[i] is not None:
            near_enough &= rendered.depth <= limits[i]
        keep = np.zeros(rendered.depth.shape, dtype=bool)
        keep[::stride, ::stride] = True
        keep &= opaque & near_enough
        points.append(lift_pixels(rendered.depth, keep, views.intrinsics[i], views.c2w[i]))
        photo = views.images[i].detach().cpu().float().numpy()
        colours.append(to_uint8(photo[keep]))
        per_view.append({
            "name": name,
            "points": int(keep.sum()),
            "opaque_fraction": float(opaque.mean()),  # pixels above min_accumulation
            "within_max_depth_fraction": float(near_enough.mean()),
            "median_accumulation": float(np.median(rendered.accumulation)),
            "median_depth": float(np.median(rendered.depth)),
            "max_depth": None if limits[i] is None else float(limits[i]),
            "c2w": views.c2w[i].detach().cpu().double().tolist(),
            "intrinsics": views.intrinsics[i].detach().cpu().double().tolist(),
        })
    xyz = np.concatenate(points) if points else np.zeros((0, 3))
    write_ply(out_dir / "points.ply", xyz, np.concatenate(colours) if colours else np.zeros((0, 3), np.uint8))
    summary = {
        "points": int(len(xyz)),
        "views": per_view,
        "height": views.height,
        "width": views.width,
        "min_accumulation": min_accumulation,
        "stride": stride,
        "scale": scale,
        "units": "scene units (file units x scale), the model's recentred frame; depth = camera z-depth",
    }
    (out_dir / "export.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def render_without_test_frames(model: nn.Module, datamodule, ckpt_path: str | Path, out_dir: str | Path,
                               video_scale: float = 0.5) -> list[Path]:
    """What `test` does on a split with no test frames (own photos: `train_frames`, or LLFF `test_every: 0`): no
    metrics, but the trained model's depth maps of the train views, its point cloud and the spiral video, in
    `out_dir`. Loads the weights of `ckpt_path` into `model` (a `SimpleNeRF`).

    Returns:
        The written files and folders.
    """
    from simplenerf.viz.video import render_scene_video

    model.load_state_dict(torch.load(ckpt_path, map_location="cpu", weights_only=False)["state_dict"])
    model.eval()
    scene, out_dir = datamodule.scene, Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    export_geometry(model.nerf, scene.views.subset(scene.split.train), datamodule.near, model.hparams.chunk, out_dir,
                    scale=scene.scale)
    with torch.no_grad():
        video, *_ = render_scene_video(model, datamodule, out_dir / "video_spiral.mp4", "spiral",
                                       scale=video_scale)
    return [out_dir / "depth", out_dir / "points.ply", video]
