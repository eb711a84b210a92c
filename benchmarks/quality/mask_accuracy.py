"""Are a trained run's reliability masks right? (docs/results.md "Where the blur and the streaks come from", 10.)

A mask (paper Sec. 4.2) decides per ray which of two depths supervises the other: +1, the other depth (an
augmentation's, or for L_cfc the main fine one) trains the main one; -1, the reverse; 0, neither. This scores that
decision against an independent depth: SfM keypoints of the TRAIN views triangulated, poses fixed, from all the
non-test frames (`evaluation.heldout_depth.reference_observations`, the held-out depth's reference, which also sees
the frames the model never saw). At those keypoints the run renders every depth as in training (deterministic
samples), each depth pair gets the mask the training step would give it, and for each pair this prints:

- the share of +1, -1 and 0;
- precision: on +1 rays the share where the other depth is the closer one to SfM; on -1 rays, the main depth;
- the mean relative depth error |z - z_sfm| / z_sfm of both depths on the +1 and on the -1 rays;
- the oracle: on all rays, the share where the other depth is the closer one;
- the same on the rays where the two depths differ by more than 5% of the SfM depth, where the choice matters.

A mask at chance has a precision near the oracle's share; a mask worth its loss, well above it.

    python -m benchmarks.quality.mask_accuracy RUN [--cache DIR] [--ckpt_path CKPT] [-- CLI overrides]

RUN is a run folder (config.yaml, checkpoints/last.ckpt); `--cache` is where the SfM reference is cached (a sweep's
runs: <sweep>/cache/sparse_depth, where its held-out depth put it). Prints one JSON line; augmentations that the run's
`LossWeightSchedule` retires from step 0 (never trained, e.g. an ablation's) are left out and named under
"untrained", as `simplenerf heldout-depth` does.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Collection
from pathlib import Path

import numpy as np
import torch

from simplenerf.commands import split_overrides
from simplenerf.evaluation.heldout_depth import keypoint_rays, reference_observations, train_view_observations
from simplenerf.method.reliability import ReliabilityMask, ReprojectionErrors
from simplenerf.run.callbacks import untrained_augmentations
from simplenerf.run.cli import load_for_tool


def _mean(values: np.ndarray) -> float:
    """The mean of an array, nan when it is empty."""
    return float(values.mean()) if values.size else float("nan")


def pair_scores(z_main: np.ndarray, z_other: np.ndarray, z_sfm: np.ndarray, mask: np.ndarray,
                disagree: float = 0.05) -> dict[str, float]:
    """The scores of one mask [R] (values -1, 0, +1) for depths z_main, z_other [R] against z_sfm [R].

    Returns shares of each mask value, the precision of +1 (other closer where +1) and of -1 (main closer where -1),
    the mean relative errors of both depths on the +1 and the -1 rays (nan where a value has no ray), the oracle
    share (other closer, all rays), and under "disagree" the same on the rays where the two depths differ by more than
    `disagree` of the SfM depth (where the mask's choice matters: elsewhere either depth is about as good)."""
    e_main, e_other = np.abs(z_main - z_sfm) / z_sfm, np.abs(z_other - z_sfm) / z_sfm
    other_closer = e_other < e_main
    plus, minus = mask == 1, mask == -1
    scores: dict = {"rays": int(len(mask)), "oracle_other_closer": _mean(other_closer)}
    for value, label in ((1, "plus"), (-1, "minus"), (0, "zero")):
        scores[f"share_{label}"] = _mean(mask == value)
    scores["precision_plus"], scores["precision_minus"] = _mean(other_closer[plus]), _mean(~other_closer[minus])
    for rays, label in ((plus, "plus"), (minus, "minus")):
        scores[f"error_main_{label}"], scores[f"error_other_{label}"] = _mean(e_main[rays]), _mean(e_other[rays])
    if disagree:
        apart = np.abs(z_main - z_other) / z_sfm > disagree
        scores["disagree"] = {"share": float(apart.mean()),
                              **pair_scores(z_main[apart], z_other[apart], z_sfm[apart], mask[apart], disagree=0)}
    return scores


def masked_pairs(model, untrained: Collection[str] = ()) -> list[tuple[str, ReliabilityMask | None, str, str]]:
    """The masked depth pairs of `model` as (term name, mask, main render, other render): each augmentation with the
    main depth of its stage, but those named in `untrained` (never trained: their depth says nothing about the run),
    and L_cfc's (main coarse, fine) where the objective has a coarse-fine mask."""
    pairs = [(aug.name, aug.mask, aug.stage, aug.name) for aug in model.augmentations if aug.name not in untrained]
    if model.objective.coarse_fine_mask is not None:
        pairs.append(("cfc", model.objective.coarse_fine_mask, "coarse", "fine"))
    return pairs


@torch.no_grad()
def mask_accuracy(model, scene, near: float, cache: str, chunk: int = 4096,
                  untrained: Collection[str] = ()) -> dict[str, dict[str, float]]:
    """`pair_scores` of every masked depth pair of `model` (`masked_pairs`) at the reference SfM keypoints of the
    train views of `scene`."""
    pairs = masked_pairs(model, untrained)
    augmentations = [aug for aug in model.augmentations if aug.name not in untrained]
    views = scene.views.subset(scene.split.train)
    rays, z_sfm = keypoint_rays(views, train_view_observations(scene, reference_observations(scene, cache)), near)
    render = model.nerf.render_rays_chunked(rays.rays, chunk, augmentations)
    depths = {"fine": render.depth, "coarse": render.coarse_depth, **render.augmented_depth}
    z_sfm = z_sfm.numpy()
    errors = ReprojectionErrors(views, rays)  # as in a training step: each depth's patch error computed once
    result = {}
    for name, mask, main, other in pairs:
        m = mask.judge(errors, main, depths[main], other, depths[other])
        m = torch.ones_like(depths[main]) if m is None else m
        result[name] = {"main": main, "other": other,
                        **pair_scores(depths[main].double().numpy(), depths[other].double().numpy(), z_sfm,
                                      m.round().long().numpy())}
    return result


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--cache", default="data/cache/sparse_depth", help="where the SfM reference is cached")
    parser.add_argument("--ckpt_path", type=Path, help="the checkpoint to load (default: RUN/checkpoints/last.ckpt)")
    args = parser.parse_args(own)
    ckpt = args.ckpt_path or args.run / "checkpoints" / "last.ckpt"
    cli = load_for_tool([str(args.run / "config.yaml")], overrides, ckpt=str(ckpt))
    model, data = cli.model, cli.datamodule
    untrained = untrained_augmentations(model, cli.trainer.callbacks)
    result = mask_accuracy(model, data.scene, data.near, args.cache, model.hparams.chunk, untrained)
    print(json.dumps({"run": str(args.run), "checkpoint": str(args.ckpt_path or "last"), "pairs": result,
                      "untrained": sorted(untrained)}))


if __name__ == "__main__":
    main()
