r"""Scores a tested run again from its saved outputs with the current definitions, without rendering
(simplenerf.evaluation.rescore), e.g.

    simplenerf rescore runs/demo
    simplenerf rescore runs/cpu/fern_simplenerf \
        --lpips_weights ../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz

The ground truth and the train views come from the run's scene, read with the config the test ran with
(`<run>/test/config.yaml`; another with --config, and the CLI's options as overrides). Prints a table: the old
scores (the run's metrics.csv), the frames scored again over the saved masks (the new metric definitions alone) and
over masks computed now (definitions and masks); writes them to `<run>/test/rescored/` (--out):
saved_masks.{csv,json}, new.{csv,json}, mask/<frame>.png. The run's own files are left as they are.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.errors import DataError
from simplenerf.evaluation.rescore import comparison_table, find_test_folder, rescore_run
from simplenerf.evaluation.visibility import MIN_VIEWS
from simplenerf.metrics.lpips import LPIPS
from simplenerf.run.cli import load_for_tool
from simplenerf.run.lock import lock_output

# Keys of a `test` config that describe that run, not the model or data, and that a config without subcommand rejects.
RUN_ONLY_KEYS = ("ckpt_path", "verbose", "weights_only")


def build_parser() -> CommandParser:
    parser = CommandParser("rescore", __doc__)
    parser.add_argument("run", help="a run folder tested by `simplenerf test`, or its test/ folder")
    parser.add_argument("--config", action="append", help="config file(s) of the run (default: <test>/config.yaml)")
    parser.add_argument("--lpips_weights", help="LPIPS weights (default: $SIMPLENERF_LPIPS_WEIGHTS, the torch cache)")
    parser.add_argument("--no_lpips", action="store_true", help="leave LPIPS out")
    parser.add_argument("--min_views", type=int, default=MIN_VIEWS, help="train views that must see a pixel")
    parser.add_argument("--out", type=Path, help="output folder (default: <test>/rescored)")
    return parser


def main(argv: Sequence[str]) -> None:
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    folder = find_test_folder(args.run)
    out = args.out or folder / "rescored"
    lock_output(out)  # not while a fit or test writes that run
    configs = args.config or [str(_without_run_keys(folder / "config.yaml", out))]
    cli = load_for_tool(configs, overrides)
    lpips_net = None if args.no_lpips else LPIPS.from_weights(args.lpips_weights)
    results = rescore_run(folder, cli.datamodule.scene, lpips_net, out, args.min_views)
    print(f"{folder}: old = its metrics.csv, saved_masks = scored again over its masks, new = over masks computed now")
    print(comparison_table(results))
    print(f"written to {out}")


def _without_run_keys(config: Path, out: Path) -> Path:
    """`config` without the top-level keys of `RUN_ONLY_KEYS`, as `<out>/config.yaml`."""
    if not config.is_file():
        raise DataError(f"{config} not found: give the run's config with --config")
    lines = config.read_text().splitlines(keepends=True)
    kept = [line for line in lines if not line.startswith(tuple(f"{key}:" for key in RUN_ONLY_KEYS))]
    out.mkdir(parents=True, exist_ok=True)
    copy = out / "config.yaml"
    copy.write_text("".join(kept))
    return copy
