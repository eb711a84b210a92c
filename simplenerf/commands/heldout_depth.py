r"""A trained run's depth error at held-out SfM points: the depth score of a real scene without reference depth
(simplenerf.evaluation.heldout_depth), e.g.

    simplenerf heldout-depth --config configs/dsnerf.yaml --ckpt_path runs/dsnerf/checkpoints/last.ckpt \
        --out runs/dsnerf/heldout_depth.json \
        --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern --data.init_args.factor 8

The CLI's options (`simplenerf fit`'s) are overrides of the config; `--config` may be the run's own
`<run>/config.yaml`. Prints one JSON line: the fine depth's error, and under "depths" that of every depth the model
renders (fine, coarse and each augmentation's, except those the run's `LossWeightSchedule` retires from step 0, which
were never trained and are named under "untrained"), and under "strips" where the fine depth's error is: per
vertical strip of the frame (`--strips N`, default 4), the keypoints' count, mean error and the share of it from
surfaces rendered behind the SfM depth; with `--out FILE` also writes it there (`<run>/heldout_depth.json` is
where `simplenerf results` looks for it).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.evaluation.heldout_depth import heldout_depth_error, heldout_observations
from simplenerf.run.callbacks import untrained_augmentations
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output


def build_parser() -> CommandParser:
    parser = CommandParser("heldout-depth", __doc__)
    parser.add_argument("--config", required=True, action="append",
                        help="config file(s) of the run, in order (e.g. <run>/config.yaml)")
    parser.add_argument("--ckpt_path", required=True, old=("--ckpt",), help="checkpoint of the trained model")
    parser.add_argument("--cache", default="data/cache/sparse_depth", help="where the SfM reference is cached")
    parser.add_argument("--out", help="also write the JSON result to this file")
    parser.add_argument("--strips", type=int, default=4,
                        help="vertical strips of the frame for the error's breakdown under \"strips\" (default 4)")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    parser = build_parser()
    args = parser.parse_args(own)
    if args.strips < 1:
        parser.error(f"--strips must be at least 1, got {args.strips}")
    if args.out:
        lock_output(Path(args.out))  # e.g. <run>/heldout_depth.json: not while a fit or test writes that run
    cli = load_for_tool(args.config, overrides, ckpt=args.ckpt_path)
    dm, model = cli.datamodule, cli.model
    untrained = untrained_augmentations(model, cli.trainer.callbacks)
    observations = heldout_observations(dm.scene, args.cache)
    result = heldout_depth_error(model, dm.scene, observations, dm.near, model.hparams.chunk, args.strips, untrained)
    line = json.dumps({"ckpt": args.ckpt_path, "overrides": overrides, **result})
    print(line)
    if args.out:
        Path(args.out).write_text(line + "\n")
