"""Videos of a trained NeRF along a camera path: [RGB | colourised depth] side by side, one mp4 (mp4v).

Frames are encoded as they are rendered (only the few frames that fix the depth colour range are held back), and
the file is written under `<name>.partial.mp4` and renamed when complete, so an interrupted render never leaves a
truncated video under the final name. The depth colours use one range for the whole video, so a colour means the
same depth in every frame; pass the range printed for one video to another to compare two models.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from simplenerf.evaluation.evaluator import colorize_depth
from simplenerf.geometry.rays import RayBundle, make_rays, pixel_grid
from simplenerf.model.nerf import NeRF


def frame_rays(c2w: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int, near: float) -> RayBundle:
    """Rays of every pixel of one camera, row-major (as `data.datasets.Frames`): c2w [3, 4], intrinsics [3, 3]."""
    uv = pixel_grid(height, width, c2w.device)
    return RayBundle.from_batch(make_rays(intrinsics[None], c2w[None], uv, width, height, near))


def downscale_intrinsics(
    intrinsics: torch.Tensor, height: int, width: int, factor: int
) -> tuple[torch.Tensor, int, int]:
    """Intrinsics [3, 3] and image size for rendering at 1/factor of the resolution (pixel (u, v) then looks where
    pixel (factor u, factor v) of the full resolution does, as in the data's convention)."""
    if factor < 1:
        raise ValueError(f"the downscaling factor must be at least 1, got {factor}")
    scaled = intrinsics.clone()
    scaled[:2, :] = intrinsics[:2, :] / factor
    return scaled, height // factor, width // factor


def depth_colour_range(depths: list[np.ndarray], percentiles: tuple[float, float] = (1.0, 99.0)) -> tuple[float, float]:
    """(closest, farthest) depth mapped to the ends of the colour map: percentiles of inverse depth over all pixels of
    depth maps [H, W] (the same statistic `evaluation.colorize_depth` uses for a single frame)."""
    inv = 1.0 / np.maximum(np.concatenate([d.ravel() for d in depths]), 1e-6)
    lo, hi = np.percentile(inv, percentiles)
    return 1.0 / max(float(hi), 1e-12), 1.0 / max(float(lo), 1e-12)


def compose_frame(rgb: np.ndarray, depth: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
    """One video frame, 8-bit RGB [H + H % 2, 2 W, 3]: rgb [H, W, 3] in [0, 1] beside depth [H, W] coloured over
    `depth_range` (closest, farthest). An odd height gets its last row repeated: the encoder needs even sizes and
    would otherwise silently crop."""
    closest, farthest = depth_range
    picture = np.round(np.clip(rgb, 0.0, 1.0) * 255).astype(np.uint8)
    frame = np.concatenate([picture, colorize_depth(depth, lo=1.0 / farthest, hi=1.0 / closest)], axis=1)
    return np.pad(frame, ((0, frame.shape[0] % 2), (0, 0), (0, 0)), mode="edge")


def partial_path(out_path: Path) -> Path:
    """Where a video is written before it is complete; keeps the suffix, from which OpenCV picks the container."""
    return out_path.with_name(f"{out_path.stem}.partial{out_path.suffix}")


def render_video(
    nerf: NeRF,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    height: int,
    width: int,
    near: float,
    chunk: int,
    out_path: str | Path,
    fps: float = 30,
    depth_range: tuple[float, float] | None = None,
    range_frames: int = 10,
) -> tuple[Path, tuple[float, float]]:
    """Renders every pose deterministically (fine network, no jitter or noise) and writes the mp4.

    Args:
        nerf: the trained model; rays are built in the dtype and on the device of its parameters.
        c2w: [N, 3, 4] camera poses, in order.
        intrinsics: [3, 3] of every frame (for height x width).
        height, width: frame size of each half of the video.
        near: NDC near plane (the data module's `near`).
        chunk: rays per forward pass.
        out_path: the .mp4 to write (its folder is created).
        fps: frames per second.
        depth_range: (closest, farthest) depth in scene units at the two ends of the colour map; None: from the
            percentiles of the first `range_frames` frames (`depth_colour_range`).
        range_frames: frames held back to fix the depth range when it is not given.

    Returns:
        The written path and the depth range used.
    """
    if c2w.ndim != 3 or c2w.shape[1:] != (3, 4) or len(c2w) == 0:
        raise ValueError(f"c2w must be [N, 3, 4] with N >= 1, got {tuple(c2w.shape)}")
    if intrinsics.shape != (3, 3):
        raise ValueError(f"intrinsics must be [3, 3], got {tuple(intrinsics.shape)}")
    param = next(nerf.parameters())
    c2w, intrinsics = c2w.to(param.device, param.dtype), intrinsics.to(param.device, param.dtype)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_path(out_path)
    size = (2 * width, height + height % 2)
    writer = cv2.VideoWriter(str(partial), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    if not writer.isOpened():
        raise OSError(f"cannot open an mp4v video writer for {partial} ({size[0]}x{size[1]} at {fps} fps)")

    held: list[tuple[np.ndarray, np.ndarray]] = []  # frames rendered before the depth range is known
    n_held = min(range_frames, len(c2w))
    was_training = nerf.training
    nerf.eval()
    try:
        for pose in tqdm(c2w, desc=f"video {out_path.name}", unit="frame"):
            out = nerf.render_rays_chunked(frame_rays(pose, intrinsics, height, width, near), chunk)
            held.append((out["rgb"].reshape(height, width, 3).float().cpu().numpy(),
                         out["depth"].reshape(height, width).float().cpu().numpy()))
            if depth_range is None:
                if len(held) < n_held:
                    continue
                depth_range = depth_colour_range([depth for _, depth in held])
            for rgb, depth in held:
                writer.write(cv2.cvtColor(compose_frame(rgb, depth, depth_range), cv2.COLOR_RGB2BGR))
            held.clear()
        writer.release()
        if not partial.is_file() or partial.stat().st_size == 0:
            raise OSError(f"the video writer produced no data in {partial}")
        os.replace(partial, out_path)
    except BaseException:
        writer.release()
        partial.unlink(missing_ok=True)
        raise
    finally:
        nerf.train(was_training)
    assert depth_range is not None
    return out_path, depth_range
