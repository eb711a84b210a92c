"""Sparse depth on both sides from the same synthetic points (data.py's point 4): 3D points in file units, seen by at
least two train views, written to the release as its sparse-depth CSVs (`csv_tables`) and given to ours as the SfM
result our pipeline would compute for them (`our_sparse_depth`, in place of the SfM: `patched_sparse_depth`); then
the rows comparing the release's sparse-depth batch with ours (`sparse_rows`).
"""

from __future__ import annotations

import contextlib

import numpy as np
import pandas as pd
import torch

from benchmarks.equivalence.rays import ray_rows
from benchmarks.equivalence.report import Row, compare, exact, flag


@contextlib.contextmanager
@contextlib.contextmanager
def patched_sparse_depth(provide):
    """Our `SceneDataModule.load_sparse_depth` with `provide(key, images, intrinsics, c2w)` in place of the SfM
    (`simplenerf.data.scene.load_or_compute_sparse_depth`): the rest of our pipeline (pool, weights, batches) runs."""
    import simplenerf.data.scene as scene_module

    saved = scene_module.load_or_compute_sparse_depth
    scene_module.load_or_compute_sparse_depth = lambda cache_dir, key, images, intrinsics, c2w, **kw: provide(
        key, images, intrinsics, c2w)
    try:
        yield
    finally:
        scene_module.load_or_compute_sparse_depth = saved


def synthetic_observations(w2c: np.ndarray, intrinsics: np.ndarray, bounds: np.ndarray, height: int, width: int,
                           points_per_view: int, rng: np.random.Generator) -> list[dict]:
    """3D points (file units) and their observations in the train views, as an SfM with fixed poses would give.

    Per view, `points_per_view` points at random sub-pixel positions, depths uniform in disparity within the view's
    bounds; each is projected into every view (w2c [V, 4, 4] OpenCV, intrinsics [V, 3, 3]). Observations must land
    inside [0.5, W - 1.5] x [0.5, H - 1.5] in front of the camera, at most one per rounded pixel of a view (the
    release keeps one depth per pixel); only points seen by at least two views are kept (a triangulated point).
    Returns one dict per view: x, y, depth (file-unit z-depth), point (id), reprojection_error, weight, and source
    [P, 4]: the point's generating view (index into the train views), pixel x, y and file-unit z-depth there.
    """
    n = len(w2c)
    points, errors, sources = [], [], []
    for i in range(n):
        xy = np.stack([rng.uniform(0.5, width - 1.5, points_per_view), rng.uniform(0.5, height - 1.5, points_per_view)],
                      axis=-1)
        z = 1.0 / rng.uniform(1.0 / bounds[i, 1], 1.0 / bounds[i, 0], points_per_view)
        cam = (np.linalg.inv(intrinsics[i]) @ np.concatenate([xy, np.ones((points_per_view, 1))], -1).T).T * z[:, None]
        c2w = np.linalg.inv(w2c[i])
        points.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
        errors.append(rng.uniform(0.05, 2.0, points_per_view))
        sources.append(np.concatenate([np.full((points_per_view, 1), i), xy, z[:, None]], -1))
    points, errors, sources = np.concatenate(points), np.concatenate(errors), np.concatenate(sources)
    obs = []
    for j in range(n):
        cam = points @ w2c[j, :3, :3].T + w2c[j, :3, 3]
        z = cam[:, 2]
        pix = cam @ intrinsics[j].T
        x, y = pix[:, 0] / pix[:, 2], pix[:, 1] / pix[:, 2]
        inside = (z > 0) & (x >= 0.5) & (x <= width - 1.5) & (y >= 0.5) & (y <= height - 1.5)
        obs.append({"inside": inside, "x": x, "y": y, "z": z})
    seen = np.sum([o["inside"] for o in obs], axis=0)
    keep = seen >= 2
    kept = []
    for o in obs:
        ids = np.where(o["inside"] & keep)[0]
        pixel = np.round(o["y"][ids]).astype(int) * width + np.round(o["x"][ids]).astype(int)
        _, first = np.unique(pixel, return_index=True)
        kept.append(ids[np.sort(first)])
    # A point that lost an observation to a shared pixel may be left with one view: drop it (no new collisions).
    counts = np.bincount(np.concatenate(kept), minlength=len(points))
    weight = 2 * np.exp(-((errors / errors.mean()) ** 2))  # DS-NeRF's weight column (unused by the release's loss)
    per_view = []
    for o, ids in zip(obs, kept, strict=True):
        ids = ids[counts[ids] >= 2]
        per_view.append({"x": o["x"][ids], "y": o["y"][ids], "depth": o["z"][ids], "point": ids,
                         "reprojection_error": errors[ids], "weight": weight[ids], "source": sources[ids]})
    return per_view


def csv_tables(per_view: list[dict]) -> list[pd.DataFrame]:
    return [pd.DataFrame({k: v[k] for k in ("x", "y", "depth", "reprojection_error", "weight")}) for v in per_view]


def our_sparse_depth(per_view: list[dict], intrinsics: torch.Tensor, c2w: torch.Tensor, scale: float):
    """What our SfM (`compute_sparse_depth` + `known_poses.collect`) holds for these points and observations:
    each observation's keypoint, and the point's z-depth in that view of OUR scene (`geometry.rays.project`). The
    point is placed in our scene from its generating view: our ray there (`pixel_rays`) at its z-depth times our
    scale (float64; triangulating instead would amplify float32 camera round-off by depth / baseline, ~1e-4 on the
    RealEstate-10K clip). Returns `SparseDepth` per view and our projections uv of the points [per view]."""
    from simplenerf.geometry.rays import pixel_rays, project
    from simplenerf.sfm.sparse_depth import SparseDepth

    k64, c64 = intrinsics.double(), c2w.double()
    out, projections = [], []
    for view, v in enumerate(per_view):
        source = torch.from_numpy(v["source"])
        at = source[:, 0].long()
        o, d = pixel_rays(k64[at], c64[at], source[:, 1:3])
        points = o + (source[:, 3] * scale)[:, None] * d
        uv, z = project(points, k64[view][None], c64[view][None])
        out.append(SparseDepth(pixels=np.stack([v["x"], v["y"]], -1).astype(np.float32), depth=z.numpy().astype(
            np.float32), reprojection_error=v["reprojection_error"].astype(np.float32), point_ids=v["point"]))
        projections.append(uv)
    return out, projections


def sparse_rows(group: str, dm, train_pre, synthetic: dict, h: int, w: int) -> list[Row]:
    """Sparse-depth targets, weights and rays of the release's batch vs ours for the same observations."""
    pool = dm.sparse_depth
    rays_ds = dm.train_dataloader().dataset
    ours = rays_ds.sparse_batch(torch.arange(len(pool)))
    # The release's sparse-depth batch over its whole pool: get_next_batch with 1 random ray and P sparse rays.
    rel_pool = train_pre.preprocessed_data_dict["sparse_depth_data"]["indices"]
    train_pre.num_rays, train_pre.num_rays_sparse_depth = 1, rel_pool.size
    train_pre.i_batch = train_pre.i_batch_sparse_depth = 0
    batch = {k: v.cpu() if isinstance(v, torch.Tensor) else v for k, v in train_pre.get_next_batch(0).items()}
    mask = batch["indices_mask_sparse_depth"]
    rel_index = batch["indices"][mask].numpy()
    # Our entries' pixels in the release's flat index (it rounds x, y: preprocess_raw_sparse_depth_data).
    u = np.clip(np.round(pool.uv[:, 0].double().numpy()), 0, w - 1).astype(int)
    v = np.clip(np.round(pool.uv[:, 1].double().numpy()), 0, h - 1).astype(int)
    ours_flat = pool.view.numpy() * h * w + v * w + u
    rows = [exact(group, "sparse depth: pixels with a depth (sorted flat index)", np.sort(ours_flat),
                  np.sort(rel_index), note=f"{len(pool)} observations of synthetic points seen by >= 2 train views")]
    if len(np.unique(ours_flat)) != len(ours_flat) or not np.array_equal(np.sort(ours_flat), np.sort(rel_index)):
        return rows
    position = {int(f): i for i, f in enumerate(rel_index)}
    at = torch.tensor([position[int(f)] for f in ours_flat])
    sel = lambda key: batch[key][mask][at]  # noqa: E731
    rows.append(compare(group, "sparse depth: targets (scaled units)", ours.depth, sel("sparse_depth_values")[:, 0],
                        1e-5, 1e-6, note="release: sparse_depth_values; ours: SparseDepthBatch.depth (z-depth in our "
                                         "camera)"))
    rows.append(compare(group, "sparse depth: our projection of the points vs the CSV's x, y (px)",
                        torch.cat(synthetic["our_uv"]), pool.uv, 0.0, 1e-4))
    rows.append(exact(group, "sparse depth: weights", ours.weight, torch.ones(len(pool)),
                      note="release SparseDepthMSE01 is plain MSE (the CSV weight column is loaded, never used); "
                           "ours weight 1 (sparse_depth_weighting off)"))
    snapped = dm.train_views.rays(pool.view, torch.from_numpy(np.stack([u, v], -1)), dm.near)
    rel = {"rays_o": sel("rays_o"), "rays_d": sel("rays_d"), "rays_o_ndc": sel("rays_o_ndc"),
           "rays_d_ndc": sel("rays_d_ndc")}
    rows.extend(ray_rows(group, "sparse-depth rays at the rounded pixel", snapped, rel,
                         note="ours switched to the release's behaviour: the ray through the nearest pixel"))
    # Deliberate difference: ours casts the ray through the keypoint itself.
    shift = (pool.uv.double() - torch.from_numpy(np.stack([u, v], -1)).double()).abs().max().item()
    exact_rays = ours.rays
    rows.append(flag(group, "sparse-depth rays: ours through the keypoint", True,
                     f"deliberate difference: ours cast through the keypoint (continuous uv), the release through "
                     f"the nearest pixel (DataPreprocessor01.preprocess_raw_sparse_depth_data rounds x, y), up to "
                     f"{shift:.2f} px apart; NDC direction max abs diff "
                     f"{(exact_rays.ndc_directions - rel['rays_d_ndc']).abs().max().item():.2e}"))
    # Self-consistency of ours: the point reached along each observing ray at its target depth is one point.
    ends = exact_rays.origins.double() + ours.depth.double()[:, None] * exact_rays.directions.double()
    ids = np.concatenate([v["point"] for v in synthetic["per_view"]])
    first = {}
    for i, p in enumerate(ids):
        first.setdefault(int(p), i)
    ref = ends[torch.tensor([first[int(p)] for p in ids])]
    rows.append(compare(group, "sparse depth: o + z d agrees across the views of a point (ours)", ends, ref, 1e-5,
                        1e-5, note="ours only: ray and depth of every observation reach the same 3D point"))
    return rows
