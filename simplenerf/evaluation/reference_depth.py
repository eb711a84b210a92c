"""Reference depth from a dense NeRF (Sec. 5.1: "a NeRF model with dense input views"; the release's
data/DenseNeRF/runs/training/train1001/Configs.json trains it on train set 1, every non-test frame).

A NeRF trained with `n_views: null` (configs/dense/) renders the fine depth of every frame of its scene, train and
test alike (the visibility masks warp train views' depth into test views). Each frame is written as
`<out_dir>/<frame name>.npy`, float32 [H, W] camera z-depth in FILE units (scene units / scene.scale): the scale
depends on the split's train bounds, so file units make one export serve every view count. A data module's
`reference_depth_dir` reads it back, multiplied by its own scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from simplenerf.data.datasets import Frames
from simplenerf.data.scene import Scene


@torch.no_grad()
def export_reference_depth(model_nerf: nn.Module, scene: Scene, near: float, chunk: int, out_dir: str | Path,
                           skip_existing: bool = False) -> list[Path]:
    """Renders the fine depth of every frame of `scene` with `model_nerf` and writes one .npy per frame.

    Args:
        model_nerf: a `simplenerf.model.nerf.NeRF` (or anything with its `render_rays_chunked`), on any device.
        scene: the scene it was trained on (its cameras and scale).
        near: the NDC near plane of the data module.
        chunk: rays per forward pass.
        out_dir: created if missing; files there of the same names are replaced.
        skip_existing: keep a frame's file that is already there and reads as a depth map of the frame's size (an
            export cut short resumes; the caller makes sure the files are this model's, as the sweep's digest does).

    Returns:
        the written paths, in frame order.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    device = next(model_nerf.parameters()).device
    frames = Frames(scene.views, near)
    written = []
    for frame in tqdm(frames, desc="reference depth", unit="frame"):
        path = out_dir / f"{frame.name}.npy"
        if skip_existing and _readable(path, (frame.height, frame.width)):
            written.append(path)
            continue
        depth = model_nerf.render_rays_chunked(frame.rays.to(device), chunk).depth.reshape(frame.height, frame.width)
        np.save(path, (depth.double().cpu().numpy() / scene.scale).astype(np.float32))
        written.append(path)
    return written


def _readable(path: Path, shape: tuple[int, int]) -> bool:
    try:
        return np.load(path).shape == shape
    except (OSError, ValueError):
        return False
