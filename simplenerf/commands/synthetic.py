"""Writes the built-in synthetic scene: a deterministic, analytically ray-traced forward-facing scene in the LLFF
layout with exact depth maps (simplenerf.data.synthetic; the demo's data and the exact tests' ground truth), e.g.

    simplenerf synthetic data/synthetic --kind objects --height 96 --width 128 --n_frames 20

Prints the scene folder it wrote: train on it with `--data.init_args.scene_dir <folder>` (LLFF loader) or let
`simplenerf.data.synthetic.SyntheticDataModule` write it itself (configs/demo.yaml).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser
from simplenerf.synthetic.generate import make_synthetic_scene
from simplenerf.synthetic.scene import SCENE_KINDS


def build_parser() -> CommandParser:
    parser = CommandParser("synthetic", __doc__)
    parser.add_argument("out_dir", type=Path, help="the scene folder to write")
    parser.add_argument("--height", type=int, default=96, help="image height at factor 1")
    parser.add_argument("--width", type=int, default=128, help="image width at factor 1")
    parser.add_argument("--n_frames", type=int, default=20, help="number of views")
    parser.add_argument("--factors", type=int, nargs="+", default=[1], help="image folders to write (images_N/)")
    parser.add_argument("--seed", type=int, default=0, help="the scene's random seed (textures, cameras)")
    parser.add_argument("--kind", choices=SCENE_KINDS, default="planes", help="planes (the tests') or objects (demo)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing scene folder")
    return parser


def main(argv: Sequence[str]) -> None:
    args = build_parser().parse_args(argv)
    path = make_synthetic_scene(
        args.out_dir, height=args.height, width=args.width, n_frames=args.n_frames, factors=args.factors,
        seed=args.seed, overwrite=args.overwrite, kind=args.kind,
    )
    print(path)
