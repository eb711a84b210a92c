"""Tested runs as one table: runs side by side, a model's runs over seeds as mean ± standard deviation, beside the
paper's published rows (Tables 1-2 layout; simplenerf.reporting.tables and records), e.g.

    simplenerf results SimpleNeRF=runs/demo DS-NeRF=runs/demo_dsnerf --scores both --depth
    simplenerf results SimpleNeRF=runs/s0 SimpleNeRF=runs/s1 DS-NeRF=runs/d0 DS-NeRF=runs/d1    (mean ± std)
    simplenerf results SimpleNeRF='runs/llff/*' DS-NeRF=runs/dsnerf_fern_2v --paper llff --csv table.csv
    simplenerf results SimpleNeRF='runs/llff/*' --per_scene
    simplenerf results ../shared/reference_scores/test10{1,2,3}1 --paper llff --depth

Rows: models in the order given. Several runs may share a NAME: runs of different scenes are averaged over all their
test frames, as the paper does (--per_scene: one table per scene); several runs of the same scene and view count
(e.g. seeds) are repeats, shown as mean ± sample standard deviation over them. Column groups: 2 / 3 / 4 views, each
LPIPS, SSIM, PSNR (--depth: also depth MAE and SROCC against the reference depth, and the held-out SfM depth error of
runs with a `<run>/heldout_depth.json`, from `simplenerf heldout-depth --out`). Masked scores by default, as in the
paper; --scores full for runs without reference depth (no masks). A folder of the authors' test runs (QA_Scores/ with
per-frame CSVs, e.g. ../shared/reference_scores/test1011) is read as is, as the row "SimpleNeRF (release)".
--csv FILE writes the shown values in long format: table, model, source, n_views, metric, value, scenes, frames, std,
runs.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser
from simplenerf.reporting.paper_scores import TABLES
from simplenerf.reporting.records import (
    HELDOUT_KEYS,
    coverage_warnings,
    expand_runs,
    load_records,
    mean_rows,
    per_scene_rows,
)
from simplenerf.reporting.tables import (
    SCORES,
    caption,
    csv_rows,
    markdown_table,
    paper_rows,
    paper_scene_notes,
    score_keys,
    table_metrics,
    table_views,
    write_csv,
)


def build_parser() -> CommandParser:
    parser = CommandParser("results", __doc__)
    parser.add_argument("runs", nargs="*", metavar="NAME=RUN_DIR",
                        help="a run folder (or its test/ folder) and the model name its row gets; several runs may "
                             "share a NAME (other scenes: averaged over their frames; the same scene: repeats, mean ± "
                             "std); RUN_DIR may be a quoted glob, or a folder of the authors' test runs (QA_Scores/ "
                             "with per-frame CSVs; NAME= optional, @N after it gives its number of views if its name "
                             "is not one of the release's)")
    parser.add_argument("--scores", choices=SCORES, default="masked",
                        help="masked (default, the paper's main tables), full (full frame), or both: 'masked (full)'")
    parser.add_argument("--depth", action="store_true",
                        help="add depth MAE and SROCC columns to each group (and the held-out SfM depth error where "
                             "runs have one)")
    parser.add_argument("--per_scene", action="store_true", help="one table per scene instead of means over scenes")
    parser.add_argument("--views", type=int, nargs="+", metavar="N",
                        help="the view-count groups to show, e.g. 2 3 4 (default: those with runs or paper values)")
    parser.add_argument("--paper", choices=list(TABLES),
                        help="also show the paper's published rows of that table, marked (paper)")
    parser.add_argument("--csv", type=Path, metavar="FILE", help="also write the shown values to FILE, long format")
    return parser


def main(argv: Sequence[str]) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.runs and args.paper is None:
        parser.error("give NAME=RUN_DIR arguments, --paper, or both")
    records = load_records(expand_runs(args.runs))
    heldout = args.depth and any(r.frames[k] for r in records for k in HELDOUT_KEYS)
    keys = [k for m in table_metrics(args.depth, heldout) for k in score_keys(m, args.scores)]
    if args.per_scene:
        # The scenes of the runs; with no runs, those the paper has per-scene numbers for.
        tables = per_scene_rows(records) or {scene: [] for scene in TABLES[args.paper].per_scene}
        if args.paper is not None:
            tables = {scene: paper_rows(args.paper, scene) + rows for scene, rows in tables.items()}
    else:
        tables = {"mean": (paper_rows(args.paper) if args.paper is not None else []) + mean_rows(records)}
        messages = [f"warning: {w}" for w in coverage_warnings(records, keys)]
        if args.paper is not None:
            messages += [f"note: {n}" for n in paper_scene_notes(records, args.paper)]
        for message in messages:
            print(message, file=sys.stderr)
    if args.scores == "masked" and records and not any(r.frames[k] for r in records for k in keys):
        print("note: no run has masked scores (its scene has no reference depth); --scores full shows the full-frame "
              "ones", file=sys.stderr)
    repeats = any(row.spread for rows in tables.values() for row in rows)
    blocks, lines = [caption(args.scores, args.per_scene, args.paper, repeats, heldout)], []
    for name, rows in tables.items():
        views = sorted(args.views) if args.views else table_views(rows, keys)
        if args.per_scene:
            blocks.append(f"### {name}")
        blocks.append(markdown_table(rows, views, args.scores, args.depth, heldout))
        lines += csv_rows(name, rows, views, args.scores, args.depth, heldout)
    print("\n\n".join(blocks))
    if args.csv is not None:
        write_csv(args.csv, lines)

