r"""Video of a trained run along the scene's camera path: [RGB | depth] side by side (simplenerf.viz.video), e.g.

    simplenerf render-video --config configs/llff.yaml --ckpt_path runs/llff/checkpoints/last.ckpt \
        --data.init_args.scene_dir data/nerf_llff_data/fern

Paths: `spiral` (LLFF: 120 frames, 2 rotations around the train views) or `recorded` (RealEstate-10K: the clip's
own cameras), or `--trajectory FILE`, a camera path exported from `simplenerf view` (its poses, size and fps).
Default: the scene's `camera_path` (LLFF: `spiral`, RealEstate-10K: `recorded`). The CLI's options (`simplenerf
fit`'s: `--data.*`, `--model.*`, ...) are overrides of the config. Writes <trainer.default_root_dir>/video_<path>.mp4
unless --out (not while a fit or test holds that run folder: docs/running.md). The depth colour range used is
printed; give it to another model's video with --depth_range to compare the two.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output
from simplenerf.viz.camera_path import read_camera_path
from simplenerf.viz.video import render_camera_path_video, render_scene_video


def build_parser() -> CommandParser:
    parser = CommandParser("render-video", __doc__)
    parser.add_argument("--config", required=True, action="append", help="config file(s) of the run, in order")
    parser.add_argument("--ckpt_path", required=True, old=("--ckpt",), help="checkpoint of the trained model")
    parser.add_argument("--path", choices=["spiral", "recorded"], help="camera path (default: see above)")
    parser.add_argument("--trajectory", help="a camera path file exported from `simplenerf view` (instead of --path)")
    parser.add_argument("--frames", type=int, default=120, help="frames of the spiral")
    parser.add_argument("--rotations", type=float, default=2, help="turns of the spiral")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="render at this times the data's resolution (0.25: a quarter, 2: twice)")
    parser.add_argument("--fps", type=float, default=30, help="frames per second")
    parser.add_argument("--depth_range", type=float, nargs=2, metavar=("CLOSEST", "FARTHEST"),
                        help="depths (scene units) at the ends of the colour map; default: from the first frames")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", help="torch device")
    parser.add_argument("--out", help="the .mp4 to write")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    path = read_camera_path(args.trajectory) if args.trajectory else None  # a bad file: one line, before loading
    cli = load_for_tool(args.config, overrides, ckpt=args.ckpt_path, device=args.device)
    if path is not None:
        out = args.out or Path(cli.trainer.default_root_dir) / f"video_{Path(args.trajectory).stem}.mp4"
        lock_output(Path(out))  # not while a fit or test writes that run
        written, n, width, height, (closest, farthest) = render_camera_path_video(
            cli.model, cli.datamodule, path, out, args.scale,
            tuple(args.depth_range) if args.depth_range else None)
        print(f"video: {written} ({n} frames of {2 * width}x{height}, {args.trajectory}; "
              f"--depth_range {closest:.4g} {farthest:.4g})")
        return
    kind = args.path or cli.datamodule.scene.camera_path
    out = args.out or Path(cli.trainer.default_root_dir) / f"video_{kind}.mp4"
    lock_output(Path(out))
    written, n, width, height, kind, (closest, farthest) = render_scene_video(
        cli.model, cli.datamodule, out, kind, args.frames, args.rotations, args.scale, args.fps,
        tuple(args.depth_range) if args.depth_range else None,
    )
    print(f"video: {written} ({n} frames of {2 * width}x{height}, {kind}; "
          f"--depth_range {closest:.4g} {farthest:.4g})")
