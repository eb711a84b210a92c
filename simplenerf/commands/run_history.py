"""What a run logged during training, read back from its W&B files (no network or account needed), as CSV, e.g.

    simplenerf run-history runs/fern --keys 'train/mask_.*' > masks.csv
    simplenerf run-history runs/fern --keys 'train/loss_(points|views|cfc)'

One row per logged step (trainer/global_step) with the scalar values whose names match --keys (a regular
expression, default every train/ value); a run folder is the logger's save_dir (by default the run's folder).
"""

from __future__ import annotations

import csv
import re
import sys
from collections.abc import Sequence

from simplenerf.commands import CommandParser
from simplenerf.errors import DataError
from simplenerf.run.loggers import logged_history


def history_table(rows: list[dict], pattern: str) -> tuple[list[str], list[list]]:
    """Columns (`step` and the matching scalar names, sorted) and one row per step that logged any of them (a step's
    values merged)."""
    match = re.compile(pattern)
    by_step: dict[int, dict] = {}
    for row in rows:
        step = row.get("trainer/global_step")
        values = {k: v for k, v in row.items()
                  if match.fullmatch(k) and isinstance(v, (int, float)) and not isinstance(v, bool)}
        if step is None or not values:
            continue
        by_step.setdefault(int(step), {}).update(values)
    names = sorted({k for values in by_step.values() for k in values})
    return ["step", *names], [[step, *(values.get(k, "") for k in names)] for step, values in sorted(by_step.items())]


def build_parser() -> CommandParser:
    parser = CommandParser("run-history", __doc__)
    parser.add_argument("run", help="the run folder (the W&B logger's save_dir)")
    parser.add_argument("--keys", default="train/.*", help="regular expression the logged names must match")
    return parser


def main(argv: Sequence[str]) -> None:
    args = build_parser().parse_args(argv)
    try:
        header, table = history_table(logged_history(args.run), args.keys)
    except (FileNotFoundError, ValueError) as e:
        raise DataError(str(e)) from None
    if not table:
        raise DataError(f"{args.run}: no logged step has a scalar matching {args.keys!r}")
    writer = csv.writer(sys.stdout, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(table)
