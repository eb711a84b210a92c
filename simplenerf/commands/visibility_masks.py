r"""Visibility masks of a scene's test frames: the pixels the masked scores evaluate, those seen by at least
`--min_views` train views (paper Sec. 5.1 and the supplement; simplenerf.evaluation.visibility), e.g.

    simplenerf visibility-masks --config configs/llff.yaml \
        --data.init_args.scene_dir data/nerf_llff_data/fern --data.init_args.reference_depth_dir DIR

The CLI's options (`simplenerf fit`'s) are overrides of the config; the data module's split (n_views) decides the
train views.
Writes `<out>/<frame>.png` (white = visible, i.e. evaluated by the masked scores) and `<out>/<frame>.npy` (bool), by
default under `<trainer.default_root_dir>/visibility`, and prints the visible fraction of each frame. The scene needs
reference depth: the synthetic scene has it; for real scenes train a dense NeRF (configs/dense/*.yaml) and export its
depth with `simplenerf export-depth`. `simplenerf test` computes the same masks itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.evaluation.evaluator import export_visibility_masks
from simplenerf.evaluation.visibility import MIN_VIEWS
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output


def build_parser() -> CommandParser:
    parser = CommandParser("visibility-masks", __doc__)
    parser.add_argument("--config", required=True, action="append",
                        help="config file(s), in order (its data module and split)")
    parser.add_argument("--out", help="output folder (default: <trainer.default_root_dir>/visibility)")
    parser.add_argument("--min_views", type=int, default=MIN_VIEWS, help="train views that must see a pixel")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    cli = load_for_tool(args.config, overrides)
    dm = cli.datamodule
    out = Path(args.out or Path(cli.trainer.default_root_dir) / "visibility")
    lock_output(out)  # not while a fit or test writes that run
    fractions = export_visibility_masks(dm.scene, out, args.min_views)
    print(f"visibility masks of {len(fractions)} test frames (train frames {dm.scene.split.train}) in {out}:")
    for name, fraction in fractions.items():
        print(f"  {name}: {100 * fraction:.1f}% visible")
