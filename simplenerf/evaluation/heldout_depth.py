"""Held-out SfM depth: an honest depth reference for real scenes without a dense NeRF.

SfM points are triangulated (poses fixed) from ALL non-test frames of a scene. Their observations in the frames that
are neither training nor test frames ("held-out" frames) are keypoints with a known depth that the few-view model
never saw; the model's rendered depth at those keypoints is compared with the SfM depth.
"""

from __future__ import annotations

import numpy as np
import torch

from simplenerf.data.colmap import SparseDepth
from simplenerf.data.scene import Scene
from simplenerf.data.sparse_depth import load_or_compute_sparse_depth
from simplenerf.model.nerf import NeRF


def heldout_observations(scene: Scene, cache_dir: str, scene_key: str) -> dict[int, SparseDepth]:
    """SfM observations in the held-out frames (frame index -> keypoints and depths), cached in `cache_dir`."""
    test = set(scene.split.test)
    reference_frames = [i for i in range(len(scene.views)) if i not in test]
    views = scene.views.subset(reference_frames)
    key = {"scene": scene_key, "views": reference_frames, "height": views.height, "width": views.width,
           "purpose": "held-out reference"}
    per_view = load_or_compute_sparse_depth(cache_dir, key, views.images, views.intrinsics, views.c2w)
    train = set(scene.split.train)
    return {frame: sd for frame, sd in zip(reference_frames, per_view, strict=True) if frame not in train and len(sd)}


@torch.no_grad()
def heldout_depth_error(
    nerf: NeRF, scene: Scene, observations: dict[int, SparseDepth], near: float, chunk: int = 8192
) -> dict[str, float]:
    """Relative depth error |z - z_sfm| / z_sfm of the fine depth at the held-out keypoints.

    Returns:
        mean and median relative error over all observations, their count and the number of frames.
    """
    device = next(nerf.parameters()).device
    errors = []
    for frame, sd in observations.items():
        uv = torch.from_numpy(sd.pixels).to(scene.views.c2w.dtype)
        rays = scene.views.rays(torch.full((len(sd),), frame), uv, near).to(device)
        depth = nerf.render_rays_chunked(rays, chunk)["depth"].cpu().double().numpy()
        errors.append(np.abs(depth - sd.depth) / sd.depth)
    errors_all = np.concatenate(errors)
    return {
        "rel_error_mean": float(errors_all.mean()),
        "rel_error_median": float(np.median(errors_all)),
        "points": int(errors_all.size),
        "frames": len(observations),
    }
