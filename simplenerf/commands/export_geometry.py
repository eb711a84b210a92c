r"""The geometry a trained run learned: each view's depth map and a coloured point cloud (simplenerf.viz.export), e.g.

    simplenerf export-geometry --config configs/llff.yaml --ckpt_path runs/llff/checkpoints/last.ckpt \
        --out runs/llff/geometry --data.init_args.scene_dir data/my_scene

Writes `<out>/depth/<frame>.npy` (float32 camera z-depth) and `.png` (colourised) for each train view (`--views all`:
every frame of the scene), `<out>/points.ply` (the train views' depth fused into one coloured point cloud; open it in
MeshLab, CloudCompare or Open3D) and `<out>/export.json` (cameras, counts). The CLI's options (`simplenerf fit`'s) are
overrides of the config (use the ones the run was trained with). Units: the model's scene units.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output
from simplenerf.viz.export import export_geometry


def build_parser() -> CommandParser:
    parser = CommandParser("export-geometry", __doc__)
    parser.add_argument("--config", required=True, action="append", help="config file(s) of the run, in order")
    parser.add_argument("--ckpt_path", required=True, old=("--ckpt",), help="checkpoint of the trained model")
    parser.add_argument("--out", help="output folder (default: <trainer.default_root_dir>/geometry)")
    parser.add_argument("--views", choices=["train", "all"], default="train",
                        help="export the train views (default) or every frame of the scene")
    parser.add_argument("--min_accumulation", type=float, default=0.9,
                        help="point cloud: keep pixels whose accumulated opacity is above this (default 0.9)")
    parser.add_argument("--far_factor", type=float, default=1.25,
                        help="point cloud: drop pixels deeper than this x the view's far bound, i.e. the background "
                        "(default 1.25; 0 keeps every depth)")
    parser.add_argument("--stride", type=int, default=1, help="point cloud: every N-th pixel in each direction")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", help="torch device")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    cli = load_for_tool(args.config, overrides, ckpt=args.ckpt_path, device=args.device)
    dm, model = cli.datamodule, cli.model
    scene = dm.scene
    indices = scene.split.train if args.views == "train" else list(range(len(scene.views)))
    max_depth = None if args.far_factor <= 0 else [args.far_factor * float(scene.bounds[i, 1]) for i in indices]
    out = Path(args.out) if args.out else Path(cli.trainer.default_root_dir) / "geometry"
    lock_output(out)  # not while a fit or test writes that run
    summary = export_geometry(
        model.nerf, scene.views.subset(indices), dm.near, model.hparams.chunk, out,
        min_accumulation=args.min_accumulation, max_depth=max_depth, stride=args.stride, scale=float(scene.scale),
    )
    print(f"geometry: {out}/depth/ ({len(indices)} depth maps of {summary['width']}x{summary['height']}), "
          f"{out}/points.ply ({summary['points']} points)")
    if summary["points"] == 0:
        opaque = max(v["opaque_fraction"] for v in summary["views"])
        print(f"geometry: no pixel passed both limits (at most {100 * opaque:.0f}% of a view's pixels have an "
              f"accumulated opacity above {args.min_accumulation}); lower --min_accumulation or --far_factor, or "
              f"train longer")
