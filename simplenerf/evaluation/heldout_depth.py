"""Held-out SfM depth: an honest depth reference for real scenes without a dense NeRF.

SfM points are triangulated (poses fixed) from ALL non-test frames of a scene. Their observations in the frames that
are neither training nor test frames ("held-out" frames) are keypoints with a known depth that the few-view model
never saw; the model's rendered depth at those keypoints is compared with the SfM depth.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING

import numpy as np
import torch

from simplenerf.data.batches import RayBatch
from simplenerf.data.scene import Scene
from simplenerf.sfm.sparse_depth import SparseDepth, load_or_compute_sparse_depth

if TYPE_CHECKING:
    from simplenerf.geometry.views import Views
    from simplenerf.method.module import SimpleNeRF


def reference_observations(scene: Scene, cache_dir: str) -> dict[int, SparseDepth]:
    """SfM observations (frame index -> keypoints and depths) triangulated, poses fixed, from all the non-test frames,
    train frames included; cached in `cache_dir`, keyed by the images and cameras (not the folder: a moved scene
    reuses its cached reference, as the training sparse depth does)."""
    test = set(scene.split.test)
    reference_frames = [i for i in range(len(scene.views)) if i not in test]
    views = scene.views.subset(reference_frames)
    key = {"views": reference_frames, "height": views.height, "width": views.width,
           "purpose": "held-out reference"}
    per_view = load_or_compute_sparse_depth(cache_dir, key, views.images, views.intrinsics, views.c2w)
    return {frame: sd for frame, sd in zip(reference_frames, per_view, strict=True) if len(sd)}


def heldout_observations(scene: Scene, cache_dir: str) -> dict[int, SparseDepth]:
    """`reference_observations` in the held-out frames (neither train nor test)."""
    train = set(scene.split.train)
    return {frame: sd for frame, sd in reference_observations(scene, cache_dir).items()
            if frame not in train}


def train_view_observations(scene: Scene, observations: dict[int, SparseDepth]) -> list[SparseDepth]:
    """The reference observations (`reference_observations`) of each train view of `scene`, in the train views'
    order; an empty one where SfM saw nothing in a view."""
    empty = SparseDepth(np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros(0, np.float32),
                        np.zeros(0, np.int64))
    return [observations.get(frame, empty) for frame in scene.split.train]


def keypoint_rays(views: Views, observations: list[SparseDepth], near: float) -> tuple[RayBatch, torch.Tensor]:
    """The rays through the keypoints of `observations` (those of view i of `views` at index i) and their SfM depths
    [R], in the views' dtype."""
    view = torch.cat([torch.full((len(sd),), i) for i, sd in enumerate(observations)])
    uv = torch.from_numpy(np.concatenate([sd.pixels for sd in observations])).to(views.c2w.dtype)
    depth = torch.from_numpy(np.concatenate([sd.depth for sd in observations])).to(uv.dtype)
    return RayBatch(views.rays(view, uv, near), torch.zeros(len(view), 3, dtype=uv.dtype), view, uv), depth


@torch.no_grad()
def heldout_depth_error(
    model: SimpleNeRF, scene: Scene, observations: dict[int, SparseDepth], near: float, chunk: int = 8192,
    strips: int = 4, untrained: Collection[str] = (),
) -> dict[str, object]:
    """Relative depth error |z - z_sfm| / z_sfm of the fine depth at the held-out keypoints, and under "depths" the
    same for every depth `model.render` gives: fine, coarse and each augmentation's (at the main model's samples of
    its stage, as in training; deterministic here), except the augmentations named in `untrained` (retired from step
    0 by the run's schedule: their fields are as initialised, so their depths say nothing about the run).

    Where the fine depth's error comes from, under "strips": the frame cut into `strips` vertical strips, left to right
    (a keypoint at column u is in strip floor(u * strips / width)), and in each the keypoints' count, their mean error
    and the share of their summed error from keypoints rendered behind the SfM depth (a near surface pushed back)
    rather than in front (a far one pulled forward, as the streaks are; docs/results.md, 16 and 17).

    Returns:
        mean and median relative error of the fine depth over all observations, their count, the number of frames,
        "depths": {name: {"rel_error_mean", "rel_error_median"}}, "untrained": the augmentations left out (sorted),
        and "strips": {"points", "rel_error_mean", "behind_share"}, each a list left to right.
    """
    if strips < 1:
        raise ValueError(f"strips must be at least 1, got {strips}")
    unknown = set(untrained) - {aug.name for aug in model.augmentations}
    if unknown:
        raise ValueError(f"untrained names {sorted(unknown)}, not among the model's augmentations "
                         f"{[aug.name for aug in model.augmentations]}")
    augmentations = [aug for aug in model.augmentations if aug.name not in untrained]
    device = next(model.parameters()).device
    errors: dict[str, list[np.ndarray]] = {}
    strip_of, behind = [], []
    for frame, sd in observations.items():
        strip_of.append(np.clip(np.floor(sd.pixels[:, 0] * strips / scene.views.width), 0, strips - 1).astype(int))
        uv = torch.from_numpy(sd.pixels).to(scene.views.c2w.dtype)
        rays = scene.views.rays(torch.full((len(sd),), frame), uv, near).to(device)
        render = model.nerf.render_rays_chunked(rays, chunk, augmentations)
        depths = {"fine": render.depth, "coarse": render.coarse_depth, **render.augmented_depth}
        for name, depth in depths.items():
            depth = depth.cpu().double().numpy()
            errors.setdefault(name, []).append(np.abs(depth - sd.depth) / sd.depth)
            if name == "fine":
                behind.append(depth > sd.depth)
    stats = {}
    for name, parts in errors.items():
        e = np.concatenate(parts)
        stats[name] = {"rel_error_mean": float(e.mean()), "rel_error_median": float(np.median(e))}
    fine, strip_of, behind = np.concatenate(errors["fine"]), np.concatenate(strip_of), np.concatenate(behind)
    per_strip: dict[str, list] = {"points": [], "rel_error_mean": [], "behind_share": []}
    for i in range(strips):
        e, b = fine[strip_of == i], behind[strip_of == i]
        per_strip["points"].append(int(e.size))
        per_strip["rel_error_mean"].append(float(e.mean()) if e.size else None)
        per_strip["behind_share"].append(float(e[b].sum() / e.sum()) if e.sum() > 0 else None)
    return {**stats["fine"], "points": int(fine.size), "frames": len(observations), "depths": stats,
            "untrained": sorted(untrained), "strips": per_strip}
