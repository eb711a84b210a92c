"""How well do a scene's train views register, and can the patch comparison of eq. 6 tell a right depth from a wrong
one there? (docs/results.md "Where the blur and the streaks come from", 18.) No model is read.

The reference is the held-out depth's: SfM points triangulated, poses fixed, from all the non-test frames
(`evaluation.heldout_depth.reference_observations`). For a point observed in a train view a and in its nearest train
view b, the ray through a's keypoint at the point's depth in a is projected into b; `registration` is how far that
lands from b's own keypoint of the same point (pixels). A few pixels mean the poses and the photos disagree by that
much, and a k x k patch comparison at the right depth compares patches that are offset by it.

`patch_test`, at every train keypoint of the reference (its SfM depth z taken as the right depth), with the patch
error of `method.reliability` (k = `--patch_size`, e_tau = `--threshold`), for each `--search_radius` s:
- the right depth's error (median) and the share below e_tau;
- `beats_every_farther`: the share where it is below the error of every depth from 1.3 z to 8 z (48 steps), the
  depths a simpler model's background would offer;
- `right_wins` and `farther_wins`: the share where eq. 6 between z and the best of those farther depths trusts z,
  and where it trusts the farther one.

`--region X0,X1 --max_depth D` splits the points: those that some held-out frame sees in columns [X0, X1) of its
width (fractions) nearer than D scene units, and the others (fern's near leaves in front of the wall: 0.75,1 and 2.0).

    python -m benchmarks.quality.registration CONFIG [--cache DIR] [--search_radius 0,1,2] [-- CLI overrides]

CONFIG is a run's config.yaml (or any config naming the scene); overrides such as `--data.init_args.factor 8` choose
the resolution. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import torch

from simplenerf.commands import split_overrides
from simplenerf.data.batches import RayBatch
from simplenerf.data.scene import Scene
from simplenerf.evaluation.heldout_depth import keypoint_rays, reference_observations, train_view_observations
from simplenerf.geometry.views import Views
from simplenerf.method.reliability import ReprojectionErrors, ternary_mask
from simplenerf.run.cli import load_for_tool
from simplenerf.sfm.sparse_depth import SparseDepth

FARTHER = np.exp(np.linspace(np.log(1.3), np.log(8.0), 48))  # depth ratios a background would offer


def registration(views: Views, observations: list[SparseDepth], near: float) -> np.ndarray:
    """[P] pixels between where each point observed in a train view and in its nearest one projects from the first
    (its keypoint's ray at its SfM depth) and where the nearest view observed it; over every such (view, point)."""
    distances = []
    for a, b in enumerate(views.nearest.tolist()):
        first, second = observations[a], observations[b]
        common, in_a, in_b = np.intersect1d(first.point_ids, second.point_ids, return_indices=True)
        if not len(common):
            continue
        uv = torch.from_numpy(first.pixels[in_a]).to(views.c2w.dtype)
        rays = views.rays(torch.full((len(common),), a), uv, near)
        points = rays.origins + torch.from_numpy(first.depth[in_a]).to(uv.dtype)[:, None] * rays.directions
        uv_b, _ = views.project(points, torch.full((len(common),), b))
        distances.append((uv_b - torch.from_numpy(second.pixels[in_b]).to(uv.dtype)).norm(dim=-1).numpy())
    return np.concatenate(distances) if distances else np.zeros(0)


def patch_test(views: Views, rays: RayBatch, depth: torch.Tensor, patch_size: int, threshold: float,
               search_radius: int) -> dict[str, float]:
    """Eq. 6 between the right depth [R] of `rays` and the best farther one (`FARTHER`), on the rays where both
    errors are finite (`patch_size` k, e_tau `threshold`, `search_radius` s of `PatchReprojectionMask`)."""
    errors = ReprojectionErrors(views, rays)
    right = errors("right", depth, patch_size, True, search_radius)
    farther = torch.stack([errors(f"x{r:.3f}", depth * float(r), patch_size, True, search_radius) for r in FARTHER])
    farther = farther.min(dim=0).values
    ok = torch.isfinite(right) & torch.isfinite(farther)
    right, farther = right[ok], farther[ok]
    mask = ternary_mask(right, farther, threshold)  # +1: the farther depth is trusted, -1: the right one
    return {"rays": int(ok.sum()), "right_error_median": float(right.median()) if len(right) else float("nan"),
            "right_below_threshold": float((right < threshold).float().mean()),
            "beats_every_farther": float((right < farther).float().mean()),
            "right_wins": float((mask == -1).float().mean()), "farther_wins": float((mask == 1).float().mean())}


def region_points(scene: Scene, observations: dict[int, SparseDepth], columns: tuple[float, float],
                  max_depth: float) -> np.ndarray:
    """Ids of the points that a held-out frame (neither train nor test) sees in `columns` (fractions of its width,
    [x0, x1)) nearer than `max_depth`."""
    train = set(scene.split.train)
    ids = [sd.point_ids[(sd.pixels[:, 0] >= columns[0] * scene.views.width)
                        & (sd.pixels[:, 0] < columns[1] * scene.views.width) & (sd.depth < max_depth)]
           for frame, sd in observations.items() if frame not in train]
    return np.unique(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int64)


def _summary(distances: np.ndarray) -> dict[str, float]:
    if not distances.size:
        return {"points": 0}
    return {"points": int(distances.size), "median_px": float(np.median(distances)),
            "p90_px": float(np.quantile(distances, 0.9))}


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", help="a run's config.yaml, or any config naming the scene")
    parser.add_argument("--cache", default="data/cache/sparse_depth", help="where the SfM reference is cached")
    parser.add_argument("--search_radius", default="0,1,2", help="comma-separated radii s to compare (pixels)")
    parser.add_argument("--patch_size", type=int, default=5)
    parser.add_argument("--threshold", type=float, default=0.1, help="e_tau")
    parser.add_argument("--region", help="X0,X1: split the points by where a held-out frame sees them")
    parser.add_argument("--max_depth", type=float, default=float("inf"), help="with --region: nearer than this")
    args = parser.parse_args(own)
    radii = [int(r) for r in args.search_radius.split(",")]
    data = load_for_tool([args.config], overrides, stage="fit").datamodule
    scene, views = data.scene, data.train_views
    observations = reference_observations(scene, args.cache)
    per_view = train_view_observations(scene, observations)
    groups = {"all": [np.ones(len(sd), bool) for sd in per_view]}
    if args.region:
        x0, x1 = (float(x) for x in args.region.split(","))
        inside = region_points(scene, observations, (x0, x1), args.max_depth)
        groups = {"region": [np.isin(sd.point_ids, inside) for sd in per_view],
                  "others": [~np.isin(sd.point_ids, inside) for sd in per_view]}
    result: dict = {"config": args.config, "overrides": overrides, "height": views.height, "width": views.width}
    for name, keep in groups.items():
        kept = [SparseDepth(sd.pixels[k], sd.depth[k], sd.reprojection_error[k], sd.point_ids[k])
                for sd, k in zip(per_view, keep, strict=True)]
        rays, depth = keypoint_rays(views, kept, data.near)
        result[name] = {"registration": _summary(registration(views, kept, data.near)),
                        "patch_test": {str(s): patch_test(views, rays, depth, args.patch_size, args.threshold, s)
                                       for s in radii}}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
