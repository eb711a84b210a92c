"""Results tables in the layout of the paper's Tables 1-2: one row per model, a column group per number of train views
(2 / 3 / 4), each group LPIPS ↓, SSIM ↑, PSNR ↑ (the paper's order), optionally depth MAE ↓ and SROCC ↑ after them.

Pipeline: `NAME=RUN_DIR` arguments -> `expand_runs` -> `load_records` (one `Record` per tested run: model, scene,
view count, the scores of its `test/summary.json`) -> `mean_rows` (one `Row` per model: per view count, the mean over
the model's scenes) or `per_scene_rows` (one table per scene, the supplement's per-scene layout) -> `markdown_table`
/ `csv_rows`. `tools/results_table.py` is the command line (`main` here).

Names: a "key" is a field of summary.json (`masked_lpips`, `lpips`, ...); a "metric" is its base name (`lpips`); the
scores choice maps metrics to keys: "masked" -> `masked_<metric>`, "full" -> `<metric>`, "both" -> both, shown as
"masked (full)" like the supplement's "values within parenthesis show unmasked scores".

Masked is the default because the paper's main tables are masked scores (pixels seen by at least two train views,
Sec. 5.1 and the supplement; SPEC 7-8: the masked 2-view LLFF means PSNR 19.57 / SSIM 0.650 / LPIPS 0.269 are exactly
Table 1's SimpleNeRF row), so measured rows compare with the published ones only in this mode.

This module imports no torch or Lightning, so the table tool starts at once.
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from simplenerf.errors import DataError
from simplenerf.evaluation.paper_scores import TABLES

METRICS = ("lpips", "ssim", "psnr")
DEPTH_METRICS = ("depth_mae", "depth_srocc")
# Every score of the shared summary.json format, full-frame then masked.
KEYS = (*METRICS, *DEPTH_METRICS, *(f"masked_{m}" for m in (*METRICS, *DEPTH_METRICS)))
HEADERS = {"lpips": "LPIPS ↓", "ssim": "SSIM ↑", "psnr": "PSNR ↑", "depth_mae": "MAE ↓", "depth_srocc": "SROCC ↑"}
SCORES = ("masked", "full", "both")
CSV_FIELDS = ("table", "model", "source", "n_views", "metric", "value", "scenes")
MISSING = "-"


@dataclass(frozen=True)
class Record:
    """One tested run: the model name it was given, its scene, number of train views and summary scores."""

    model: str
    scene: str
    n_views: int
    scores: dict[str, float | None]  # every key of KEYS; None where the summary has no value
    path: Path  # the summary.json it was read from


@dataclass(frozen=True)
class Row:
    """One table row. `values[(n_views, key)]` is the mean over the scenes `scenes[n_views]` (absent: no value);
    `printed` gives a value as published (the paper's digits), `paper` marks a published reference row."""

    model: str
    values: dict[tuple[int, str], float]
    scenes: dict[int, tuple[str, ...]]
    printed: dict[tuple[int, str], str] = field(default_factory=dict)
    paper: bool = False

    @property
    def label(self) -> str:
        return f"{self.model} (paper)" if self.paper else self.model


def _unique(items: Iterable[str]) -> list[str]:
    return list(dict.fromkeys(items))


def table_metrics(depth: bool) -> tuple[str, ...]:
    """The metrics of one view-count group, in the paper's order."""
    return (*METRICS, *DEPTH_METRICS) if depth else METRICS


def score_keys(metric: str, scores: str) -> tuple[str, ...]:
    """The summary keys a metric's cell shows: masked, full-frame, or both (masked first)."""
    if scores not in SCORES:
        raise ValueError(f"scores must be one of {SCORES}, got {scores!r}")
    return {"masked": (f"masked_{metric}",), "full": (metric,), "both": (f"masked_{metric}", metric)}[scores]


def expand_runs(args: Sequence[str]) -> list[tuple[str, Path]]:
    """`NAME=RUN_DIR` arguments -> (name, run folder) pairs in the order given. A RUN_DIR with glob characters
    (`runs/llff/*`, quoted so the shell leaves it) stands for the folders it matches, sorted by path."""
    runs = []
    for arg in args:
        name, sep, pattern = arg.partition("=")
        if not sep or not name or not pattern:
            raise DataError(f"{arg!r}: expected NAME=RUN_DIR, e.g. SimpleNeRF=runs/fern_2v or SimpleNeRF='runs/llff/*'")
        if any(c in pattern for c in "*?["):
            matches = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_dir())
            if not matches:
                raise DataError(f"{pattern}: no run folder matches this pattern (given for {name})")
            runs.extend((name, path) for path in matches)
        else:
            runs.append((name, Path(pattern)))
    return runs


def load_record(model: str, path: Path) -> Record:
    """The scores of one run: `path` is a run folder (reads its test/summary.json) or its test output folder."""
    path = Path(path)
    file = path / "summary.json" if (path / "summary.json").is_file() else path / "test" / "summary.json"
    if not file.is_file():
        raise DataError(f"{file} not found: test the run first with `python -m simplenerf test --config ... "
                        f"--ckpt_path last` (run folder {path}, given for {model})")
    try:
        summary = json.loads(file.read_text())
    except json.JSONDecodeError as e:
        raise DataError(f"{file}: not valid JSON ({e})") from None
    if not isinstance(summary, dict):
        raise DataError(f"{file}: expected a JSON object with the test summary")
    scene, n_views = summary.get("scene"), summary.get("n_views")
    if not isinstance(scene, str) or not scene or type(n_views) is not int or n_views < 1:
        raise DataError(f"{file}: expected \"scene\" (the scene folder name) and \"n_views\" (a positive integer), "
                        f"found scene={scene!r}, n_views={n_views!r}; re-run `python -m simplenerf test ...` with the "
                        "current code to rewrite it")
    scores: dict[str, float | None] = {}
    for key in KEYS:
        value = summary.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise DataError(f"{file}: \"{key}\" should be a number or null, found {value!r}")
        scores[key] = None if value is None else float(value)
    return Record(model, scene, n_views, scores, file)


def load_records(runs: Sequence[tuple[str, Path]]) -> list[Record]:
    """The records of (model name, run folder) pairs, in order. Two runs of one model on the same scene and view
    count are an error (which one would the table show?)."""
    records: list[Record] = []
    seen: dict[tuple[str, str, int], Path] = {}
    for model, path in runs:
        record = load_record(model, path)
        key = (record.model, record.scene, record.n_views)
        if key in seen:
            raise DataError(f"{seen[key]} and {record.path} are both {model} on {record.scene} with "
                            f"{record.n_views} views: give one of them another NAME or leave it out")
        seen[key] = record.path
        records.append(record)
    return records


def mean_rows(records: Sequence[Record]) -> list[Row]:
    """One row per model (in order of first appearance): per view count, each score averaged over the model's scenes
    with that view count. A score some of those scenes lack has no mean (see `coverage_warnings`)."""
    rows = []
    for model in _unique(r.model for r in records):
        own = [r for r in records if r.model == model]
        values: dict[tuple[int, str], float] = {}
        scenes: dict[int, tuple[str, ...]] = {}
        for n in sorted({r.n_views for r in own}):
            group = [r for r in own if r.n_views == n]
            scenes[n] = tuple(r.scene for r in group)
            for key in KEYS:
                found = [r.scores[key] for r in group if r.scores[key] is not None]
                if found and len(found) == len(group):
                    values[(n, key)] = math.fsum(found) / len(found)
        rows.append(Row(model, values, scenes))
    return rows


def per_scene_rows(records: Sequence[Record]) -> dict[str, list[Row]]:
    """Scene (in order of first appearance) -> one row per model with that scene's scores."""
    return {scene: mean_rows([r for r in records if r.scene == scene]) for scene in _unique(r.scene for r in records)}


def coverage_warnings(records: Sequence[Record], keys: Sequence[str]) -> list[str]:
    """What makes the means of `mean_rows` not comparable: per view count, models averaged over different scene sets
    (naming each missing (model, scene, views)); and scenes lacking a shown key that the model's other scenes have."""
    warnings = []
    for n in sorted({r.n_views for r in records}):
        group = [r for r in records if r.n_views == n]
        present = {(r.model, r.scene) for r in group}
        missing = [(m, s) for m in _unique(r.model for r in group) for s in _unique(r.scene for r in group)
                   if (m, s) not in present]
        if missing:
            warnings.append(f"{n} views: models are averaged over different scenes; missing runs: "
                            + ", ".join(f"({m}, {s}, {n} views)" for m, s in missing))
    for model in _unique(r.model for r in records):
        for n in sorted({r.n_views for r in records if r.model == model}):
            group = [r for r in records if r.model == model and r.n_views == n]
            for r in group:
                lacking = [k for k in keys if r.scores[k] is None and any(o.scores[k] is not None for o in group)]
                if lacking:
                    warnings.append(f"{model}, {n} views: {r.scene} has no {', '.join(lacking)} ({r.path}), so "
                                    f"{'that mean is' if len(lacking) == 1 else 'those means are'} left out")
    return warnings


def paper_rows(table: str, scene: str | None = None) -> list[Row]:
    """The published rows of `paper_scores.TABLES[table]` (means over its scenes), or those of one scene."""
    paper = TABLES[table]
    source = paper.rows if scene is None else paper.per_scene.get(scene, {})
    scenes = paper.scenes if scene is None else (scene,)
    rows = []
    for model, printed in source.items():
        views = sorted({n for n, _ in printed})
        rows.append(Row(model, {k: float(v) for k, v in printed.items()}, {n: scenes for n in views}, dict(printed),
                        paper=True))
    return rows


def paper_scene_notes(records: Sequence[Record], table: str) -> list[str]:
    """Per view count, a note where the measured runs cover other scenes than the published means."""
    scenes = TABLES[table].scenes
    notes = []
    for n in sorted({r.n_views for r in records}):
        measured = _unique(r.scene for r in records if r.n_views == n)
        if set(measured) != set(scenes):
            notes.append(f"{n} views: the (paper) rows are means over {len(scenes)} scenes ({', '.join(scenes)}), the "
                         f"measured rows over {', '.join(measured)}")
    return notes


def _shows_any(row: Row, views: Sequence[int], keys: Sequence[str]) -> bool:
    return any((n, k) in row.values for n in views for k in keys)


def table_views(rows: Sequence[Row], keys: Sequence[str]) -> list[int]:
    """The view counts a table needs: those with measured runs, and those where a published row has a shown value."""
    views = {n for row in rows if not row.paper for n in row.scenes}
    views |= {n for row in rows if row.paper for n, k in row.values if k in keys}
    return sorted(views)


def _format(row: Row, n: int, key: str) -> str:
    if (n, key) in row.printed:
        return row.printed[(n, key)]
    if (n, key) not in row.values:
        return MISSING
    return f"{row.values[(n, key)]:.{2 if key.endswith('psnr') else 4}f}"


def cell(row: Row, n: int, metric: str, scores: str) -> str:
    """One cell: "0.2688"; "0.2688 (0.3900)" for both scores (masked, then full-frame); "-" without a value."""
    texts = [_format(row, n, key) for key in score_keys(metric, scores)]
    if all(t == MISSING for t in texts):
        return MISSING
    return texts[0] if len(texts) == 1 else f"{texts[0]} ({texts[1]})"


def _line(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown_table(rows: Sequence[Row], views: Sequence[int], scores: str = "masked", depth: bool = False) -> str:
    """The rows in Table 1's layout. Markdown has no merged header cells, so the header row names each view-count
    group above its first column, and the first body row names the metrics:

        |  | 2 views |  |  | 3 views |  |  |
        |---|---:|---:|---:|---:|---:|---:|
        | Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ |

    Published rows without a value in any shown column are left out.
    """
    metrics = table_metrics(depth)
    keys = [k for m in metrics for k in score_keys(m, scores)]
    groups = [c for n in views for c in (f"{n} views", *[""] * (len(metrics) - 1))]
    lines = [_line(["", *groups]), "|---|" + "---:|" * len(groups),
             _line(["Model", *[HEADERS[m] for _ in views for m in metrics]])]
    for row in rows:
        if row.paper and not _shows_any(row, views, keys):
            continue
        lines.append(_line([row.label.replace("|", "\\|"), *[cell(row, n, m, scores) for n in views for m in metrics]]))
    return "\n".join(lines)


def caption(scores: str, per_scene: bool, paper: str | None = None) -> str:
    """What the numbers of a table are, printed above it."""
    what = {"masked": "Masked scores (pixels seen by at least two train views), as in the paper's Tables 1-2.",
            "full": "Full-frame scores.",
            "both": "Masked scores, full-frame scores in parentheses (the supplement's layout)."}[scores]
    rows = ("One table per scene." if per_scene else
            "Each row: the mean over the model's scenes with that number of views.")
    text = f"{what} {rows} {MISSING}: no run or no score."
    if paper is not None and per_scene:
        text += (" (paper): the published per-scene numbers SPEC section 8 quotes (the supplement's per-scene tables "
                 "have no body in the .tex).")
    elif paper is not None:
        table = TABLES[paper]
        text += (f" (paper): published numbers as printed, {table.caption} ({table.label}), means over "
                 f"{len(table.scenes)} scenes.")
        if scores != "masked":
            text += " Published full-frame numbers: only those SPEC section 8 quotes."
    return text


def csv_rows(table: str, rows: Sequence[Row], views: Sequence[int], scores: str = "masked", depth: bool = False
             ) -> list[dict[str, str | int]]:
    """Long format, one line per value shown: table ("mean", or the scene in per-scene mode), model, source
    ("measured" or "paper"), n_views, metric (the summary key, e.g. masked_lpips), value (full precision; the paper's
    as printed), scenes (";"-separated, those the value averages). Cells without a value have no line."""
    out: list[dict[str, str | int]] = []
    for row in rows:
        for n in views:
            for metric in table_metrics(depth):
                for key in score_keys(metric, scores):
                    if (n, key) in row.values:
                        value = row.printed.get((n, key), repr(row.values[(n, key)]))
                        out.append({"table": table, "model": row.model, "source": "paper" if row.paper else "measured",
                                    "n_views": n, "metric": key, "value": value,
                                    "scenes": ";".join(row.scenes.get(n, ()))})
    return out


def write_csv(path: Path, lines: Sequence[dict[str, str | int]]) -> None:
    """Writes `csv_rows` output with a header line."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="results_table.py",
        description="Tested runs as a table in the layout of the paper's Tables 1-2 (markdown on stdout).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  python tools/results_table.py SimpleNeRF='runs/llff/*' DS-NeRF=runs/dsnerf_fern_2v "
               "--paper llff --csv results.csv")
    parser.add_argument("runs", nargs="*", metavar="NAME=RUN_DIR",
                        help="a run folder (or its test/ folder) and the model name its row gets; several runs may "
                             "share a NAME (its row averages their scenes); RUN_DIR may be a quoted glob")
    parser.add_argument("--scores", choices=SCORES, default="masked",
                        help="masked (default, the paper's main tables), full (full frame), or both: 'masked (full)'")
    parser.add_argument("--depth", action="store_true", help="add depth MAE and SROCC columns to each group")
    parser.add_argument("--per-scene", action="store_true", help="one table per scene instead of means over scenes")
    parser.add_argument("--views", type=int, nargs="+", metavar="N",
                        help="the view-count groups to show, e.g. 2 3 4 (default: those with runs or paper values)")
    parser.add_argument("--paper", choices=list(TABLES),
                        help="also show the paper's published rows of that table, marked (paper)")
    parser.add_argument("--csv", type=Path, metavar="FILE", help="also write the shown values to FILE, long format")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The results table command line; returns the exit status (2 after a one-line error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.runs and args.paper is None:
        parser.error("give NAME=RUN_DIR arguments, --paper, or both")
    try:
        records = load_records(expand_runs(args.runs))
    except DataError as e:
        print(f"results_table: error: {e}", file=sys.stderr)
        return 2
    keys = [k for m in table_metrics(args.depth) for k in score_keys(m, args.scores)]
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
    blocks, lines = [caption(args.scores, args.per_scene, args.paper)], []
    for name, rows in tables.items():
        views = sorted(args.views) if args.views else table_views(rows, keys)
        if args.per_scene:
            blocks.append(f"### {name}")
        blocks.append(markdown_table(rows, views, args.scores, args.depth))
        lines += csv_rows(name, rows, views, args.scores, args.depth)
    print("\n\n".join(blocks))
    if args.csv is not None:
        write_csv(args.csv, lines)
    return 0
