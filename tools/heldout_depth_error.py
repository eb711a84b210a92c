"""Depth error of a trained model at held-out SfM points (see simplenerf.evaluation.heldout_depth), e.g.

    python tools/heldout_depth_error.py --config configs/dsnerf.yaml --ckpt runs/dsnerf/checkpoints/last.ckpt \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern --data.init_args.factor 8

Everything after `--` is passed to the CLI as overrides; `--config` may be the run's own `<run>/config.yaml`. Prints
one JSON line: the fine depth's error, and under "depths" that of every depth the model renders (fine, coarse and each
augmentation's); with `--out FILE` also writes it there (`<run>/heldout_depth.json` is where
`tools/compare_runs.py` looks for it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from simplenerf.cli import run_tool, split_overrides
from simplenerf.evaluation.heldout_depth import heldout_depth_error, heldout_observations
from simplenerf.lightning_cli import load_for_tool


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True)
    parser.add_argument("--ckpt", required=True, help="checkpoint of the trained model")
    parser.add_argument("--cache", default="data/cache/sparse_depth", help="where the SfM reference is cached")
    parser.add_argument("--out", help="also write the JSON result to this file")
    args = parser.parse_args(own)
    cli = load_for_tool([args.config], overrides, ckpt=args.ckpt)
    dm, model = cli.datamodule, cli.model
    observations = heldout_observations(dm.scene, args.cache, str(dm.scene.source.resolve()))
    result = heldout_depth_error(model, dm.scene, observations, dm.near, model.hparams.chunk)
    line = json.dumps({"ckpt": args.ckpt, "overrides": overrides, **result})
    print(line)
    if args.out:
        Path(args.out).write_text(line + "\n")


if __name__ == "__main__":
    run_tool(main, "heldout_depth_error")
