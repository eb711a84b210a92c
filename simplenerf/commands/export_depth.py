r"""A dense NeRF's depth of every frame of its scene: the reference depth of the masked scores and of the depth
metrics (simplenerf.evaluation.reference_depth), e.g.

    simplenerf export-depth --config configs/dense/llff.yaml --ckpt_path runs/dense/llff/checkpoints/last.ckpt \
        --out data/reference_depth/fern --data.init_args.scene_dir data/nerf_llff_data/fern

The CLI's options (`simplenerf fit`'s) are overrides of the config (use the ones the dense NeRF was trained with).
Evaluate an n-view run against it with `--data.init_args.reference_depth_dir data/reference_depth/fern`.
RealEstate-10K: the reference for n views is the dense NeRF trained with `--data.init_args.split_views n`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.evaluation.reference_depth import export_reference_depth
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output


def build_parser() -> CommandParser:
    parser = CommandParser("export-depth", __doc__)
    parser.add_argument("--config", required=True, action="append", help="config file(s) of the dense NeRF, in order")
    parser.add_argument("--ckpt_path", required=True, old=("--ckpt",), help="checkpoint of the dense NeRF")
    parser.add_argument("--out", required=True, help="folder for <frame name>.npy (created if missing)")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu",
                        help="where to render (default: cuda if available, else cpu)")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    lock_output(Path(args.out))  # an output inside a run folder: not while a fit or test writes that run
    cli = load_for_tool(args.config, overrides, ckpt=args.ckpt_path, device=args.device)
    dm, model = cli.datamodule, cli.model
    paths = export_reference_depth(model.nerf, dm.scene, dm.near, model.hparams.chunk, args.out)
    print(f"wrote {len(paths)} depth maps to {args.out}")
