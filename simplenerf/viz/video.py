"""Videos of a trained NeRF along a camera path: [RGB | colourised depth] side by side, one mp4 (H.264).

The mp4 holds H.264 (libx264, yuv420p, moov atom first), which browsers and W&B play; PyAV's wheels ship libx264.

Frames are encoded as they are rendered (only the few frames that fix the depth colour range are held back), and
the file is written under `<name>.partial.mp4` and renamed when complete, so an interrupted render never leaves a
truncated video under the final name. The depth colours use one range for the whole video, so a colour means the
same depth in every frame; pass the range printed for one video to another to compare two models.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import lightning as L
import numpy as np
import torch
from tqdm import tqdm

from simplenerf.data.scene import SceneDataModule
from simplenerf.geometry.rays import RayBundle, make_rays, pixel_grid
from simplenerf.geometry.trajectories import TrajectoryKind
from simplenerf.model.nerf import NeRF
from simplenerf.viz.camera_path import CameraPath
from simplenerf.viz.pictures import colorize_depth, to_uint8


def frame_rays(c2w: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int, near: float) -> RayBundle:
    """Rays of every pixel of one camera, row-major (as `data.datasets.Frames`): c2w [3, 4], intrinsics [3, 3]."""
    uv = pixel_grid(height, width, c2w.device)
    return make_rays(intrinsics[None], c2w[None], uv, width, height, near)


def scale_intrinsics(
    intrinsics: torch.Tensor, height: int, width: int, scale: float
) -> tuple[torch.Tensor, int, int]:
    """Intrinsics [3, 3] and image size for rendering at `scale` times the resolution (0.25: a quarter, 2: twice;
    a NeRF renders at any size). Pixel (u, v) then looks where pixel (u / scale, v / scale) of the data does, as in
    the data's convention (integer pixel coordinates)."""
    if scale <= 0:
        raise ValueError(f"the scale must be positive, got {scale}")
    scaled = intrinsics.clone()
    scaled[:2, :] = intrinsics[:2, :] * scale
    return scaled, max(1, round(height * scale)), max(1, round(width * scale))


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
    picture = to_uint8(rgb)
    frame = np.concatenate([picture, colorize_depth(depth, lo=1.0 / farthest, hi=1.0 / closest)], axis=1)
    return np.pad(frame, ((0, frame.shape[0] % 2), (0, 0), (0, 0)), mode="edge")


def partial_path(out_path: Path) -> Path:
    """Where a video is written before it is complete; keeps the suffix, from which FFmpeg picks the container."""
    return out_path.with_name(f"{out_path.stem}.partial{out_path.suffix}")


class H264Writer:
    """Writes 8-bit RGB frames [H, W, 3] (even H and W) to an mp4 as H.264, yuv420p, with the index at the front
    (`+faststart`) so a browser starts playing before the whole file has loaded."""

    def __init__(self, path: Path, width: int, height: int, fps: float, crf: int = 18) -> None:
        import av  # here, not at the top: PyAV is needed to write a video, not to train or test

        self._av = av
        try:
            self.container = av.open(str(path), mode="w", container_options={"movflags": "+faststart"})
        except (ValueError, av.FFmpegError) as e:
            raise OSError(f"cannot open an H.264 video writer for {path} ({width}x{height} at {fps} fps): {e}") from e
        self.stream = self.container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        self.stream.width, self.stream.height, self.stream.pix_fmt = width, height, "yuv420p"
        self.stream.options = {"crf": str(crf)}

    def write(self, rgb: np.ndarray) -> None:
        for packet in self.stream.encode(self._av.VideoFrame.from_ndarray(rgb, format="rgb24")):
            self.container.mux(packet)

    def close(self) -> None:
        """Flushes the encoder and finishes the file."""
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()

    def abort(self) -> None:
        """Closes the file without flushing (it is about to be deleted)."""
        try:
            self.container.close()
        except self._av.FFmpegError:
            pass


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
    writer = H264Writer(partial, 2 * width, height + height % 2, fps)

    held: list[tuple[np.ndarray, np.ndarray]] = []  # frames rendered before the depth range is known
    n_held = min(range_frames, len(c2w))
    was_training = nerf.training
    nerf.eval()
    try:
        for pose in tqdm(c2w, desc=f"video {out_path.name}", unit="frame", disable=None):  # no bar in a log file
            out = nerf.render_rays_chunked(frame_rays(pose, intrinsics, height, width, near), chunk)
            held.append((out.rgb.reshape(height, width, 3).float().cpu().numpy(),
                         out.depth.reshape(height, width).float().cpu().numpy()))
            if depth_range is None:
                if len(held) < n_held:
                    continue
                depth_range = depth_colour_range([depth for _, depth in held])
            for rgb, depth in held:
                writer.write(compose_frame(rgb, depth, depth_range))
            held.clear()
        writer.close()
        if not partial.is_file() or partial.stat().st_size == 0:
            raise OSError(f"the video writer produced no data in {partial}")
        os.replace(partial, out_path)
    except BaseException:
        writer.abort()
        partial.unlink(missing_ok=True)
        raise
    finally:
        nerf.train(was_training)
    assert depth_range is not None
    return out_path, depth_range


def render_scene_video(
    model: L.LightningModule,
    datamodule: SceneDataModule,
    out_path: str | Path,
    kind: TrajectoryKind | None = None,
    frames: int = 120,
    rotations: float = 2,
    scale: float = 1.0,
    fps: float = 30,
    depth_range: tuple[float, float] | None = None,
) -> tuple[Path, int, int, int, TrajectoryKind, tuple[float, float]]:
    """The video of a trained module (its `nerf`, `hparams.chunk`) along its data module's camera path: the spiral
    around the train views (`kind` "spiral") or the scene's recorded path ("recorded"); None: the scene's own
    `camera_path`. Rendered at `scale` times the data's resolution with the first train view's
    intrinsics.

    Returns:
        The written path, the number of frames, the width and height of each half, the path kind and the depth range.
    """
    scene = datamodule.scene
    kind = kind or scene.camera_path
    c2w = scene.trajectory(kind, frames, rotations)
    intrinsics, height, width = scale_intrinsics(
        scene.views.intrinsics[scene.split.train[0]], scene.views.height, scene.views.width, scale
    )
    written, used_range = render_video(model.nerf, c2w, intrinsics, height, width, datamodule.near,
                                       model.hparams.chunk, out_path, fps, depth_range)
    return written, len(c2w), width, height, kind, used_range


def render_camera_path_video(
    model: L.LightningModule,
    datamodule: L.LightningDataModule,
    path: CameraPath,
    out_path: str | Path,
    scale: float = 1.0,
    depth_range: tuple[float, float] | None = None,
) -> tuple[Path, int, int, int, tuple[float, float]]:
    """The video of a trained module along a saved camera path (`simplenerf view`'s export), at the path's size / N
    and frame rate. Returns the written path, the number of frames, the width and height of each half and the depth
    range."""
    intrinsics, height, width = scale_intrinsics(path.intrinsics, path.height, path.width, scale)
    written, used_range = render_video(model.nerf, path.c2w, intrinsics, height, width, datamodule.near,
                                       model.hparams.chunk, out_path, path.fps, depth_range)
    return written, len(path.c2w), width, height, used_range
