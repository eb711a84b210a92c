"""Results tables in the layout of the paper's Tables 1-2: one row per model, a column group per number of train views
(2 / 3 / 4), each group LPIPS ↓, SSIM ↑, PSNR ↑ (the paper's order), optionally depth MAE ↓ and SROCC ↑ after them.

The rows come from `records` (tested runs and authors' release folders, averaged over ALL test frames of a model's
scenes as the paper averages, or per scene) and from `paper_scores` (the published rows); here they are laid out as
`markdown_table` / `csv_rows`. `simplenerf results` is the command line (simplenerf/commands/results.py). A model with
several runs of the same scenes (e.g. seeds) shows mean ± standard deviation over them (`records.mean_rows`).

Names: a "key" is a field of summary.json (`masked_lpips`, `lpips`, ...); a "metric" is its base name (`lpips`); the
scores choice maps metrics to keys: "masked" -> `masked_<metric>`, "full" -> `<metric>`, "both" -> both, shown as
"masked (full)" like the supplement's "values within parenthesis show unmasked scores".

Masked is the default because the paper's main tables are masked scores (pixels seen by at least two train views,
Sec. 5.1 and the supplement's Evaluation Details; the release's masked 2-view LLFF means, runs/testing/test1011/
QA_Scores.json, PSNR 19.57 / SSIM 0.650 / LPIPS 0.269, are exactly Table 1's SimpleNeRF row), so measured rows compare
with the published ones only in this mode.

This module imports no torch or Lightning, so the table command starts at once.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from simplenerf.reporting.paper_scores import TABLES
from simplenerf.reporting.records import (
    DEPTH_METRICS,
    HELDOUT_KEYS,
    METRICS,
    Record,
    Row,
    unique,
)

HEADERS = {"lpips": "LPIPS ↓", "ssim": "SSIM ↑", "psnr": "PSNR ↑", "depth_mae": "MAE ↓", "depth_srocc": "SROCC ↑",
           "heldout_rel_error_mean": "held-out err. ↓", "heldout_rel_error_median": "held-out err. median ↓"}
SCORES = ("masked", "full", "both")
CSV_FIELDS = ("table", "model", "source", "n_views", "metric", "value", "scenes", "frames", "std", "runs")
MISSING = "-"


def table_metrics(depth: bool, heldout: bool = False) -> tuple[str, ...]:
    """The metrics of one view-count group, in the paper's order; then the reference-depth ones (`depth`) and the
    held-out SfM depth error (`heldout`)."""
    return (*METRICS, *(DEPTH_METRICS if depth else ()), *(HELDOUT_KEYS if heldout else ()))


def score_keys(metric: str, scores: str) -> tuple[str, ...]:
    """The summary keys a metric's cell shows: masked, full-frame, or both (masked first)."""
    if scores not in SCORES:
        raise ValueError(f"scores must be one of {SCORES}, got {scores!r}")
    if metric in HELDOUT_KEYS:  # no mask: scored at SfM points
        return (metric,)
    return {"masked": (f"masked_{metric}",), "full": (metric,), "both": (f"masked_{metric}", metric)}[scores]


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
        measured = unique(r.scene for r in records if r.n_views == n)
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
    digits = 2 if key.endswith("psnr") else 4
    spread = f" ± {row.spread[(n, key)]:.{digits}f}" if (n, key) in row.spread else ""
    return f"{row.values[(n, key)]:.{digits}f}{spread}"


def cell(row: Row, n: int, metric: str, scores: str) -> str:
    """One cell: "0.2688"; "0.2688 (0.3900)" for both scores (masked, then full-frame); "0.2688 ± 0.0120" over
    repeats; "-" without a value."""
    texts = [_format(row, n, key) for key in score_keys(metric, scores)]
    if all(t == MISSING for t in texts):
        return MISSING
    return texts[0] if len(texts) == 1 else f"{texts[0]} ({texts[1]})"


def _line(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown_table(rows: Sequence[Row], views: Sequence[int], scores: str = "masked", depth: bool = False,
                   heldout: bool = False) -> str:
    """The rows in Table 1's layout. Markdown has no merged header cells, so the header row names each view-count
    group above its first column, and the first body row names the metrics:

        |  | 2 views |  |  | 3 views |  |  |
        |---|---:|---:|---:|---:|---:|---:|
        | Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ |

    Published rows without a value in any shown column are left out.
    """
    metrics = table_metrics(depth, heldout)
    keys = [k for m in metrics for k in score_keys(m, scores)]
    groups = [c for n in views for c in (f"{n} views", *[""] * (len(metrics) - 1))]
    lines = [_line(["", *groups]), "|---|" + "---:|" * len(groups),
             _line(["Model", *[HEADERS[m] for _ in views for m in metrics]])]
    for row in rows:
        if row.paper and not _shows_any(row, views, keys):
            continue
        lines.append(_line([row.label.replace("|", "\\|"), *[cell(row, n, m, scores) for n in views for m in metrics]]))
    return "\n".join(lines)


def caption(scores: str, per_scene: bool, paper: str | None = None, repeats: bool = False,
            heldout: bool = False) -> str:
    """What the numbers of a table are, printed above it."""
    what = {"masked": "Masked scores (pixels seen by at least two train views), as in the paper's Tables 1-2.",
            "full": "Full-frame scores.",
            "both": "Masked scores, full-frame scores in parentheses (the supplement's layout)."}[scores]
    rows = ("One table per scene: the means over its test frames." if per_scene else
            "Each row: the mean over all test frames of the model's scenes with that number of views (as the paper).")
    text = f"{what} {rows} {MISSING}: no run or no score."
    if repeats:
        text += (" Cells a ± b: mean ± sample standard deviation over a model's runs of the same scenes (e.g. "
                 "seeds); the r-th run of each scene makes repeat r.")
    if heldout:
        text += " Held-out err.: relative depth error at held-out SfM points (`simplenerf heldout-depth`), per run."
    if paper is not None and per_scene:
        text += (" (paper): the per-scene numbers of the authors' published scores (their release's runs/testing/, "
                 "QA_Scores/*_SceneWise.csv; the supplement's per-scene tables have no body in the .tex).")
    elif paper is not None:
        table = TABLES[paper]
        text += (f" (paper): published numbers as printed, {table.caption} ({table.label}), means over "
                 f"{len(table.scenes)} scenes.")
        if scores != "masked":
            text += " Published full-frame numbers: only SimpleNeRF's 2-view LLFF means."
    return text


def csv_rows(table: str, rows: Sequence[Row], views: Sequence[int], scores: str = "masked", depth: bool = False,
             heldout: bool = False) -> list[dict[str, str | int]]:
    """Long format, one line per value shown: table ("mean", or the scene in per-scene mode), model, source
    ("measured" or "paper"), n_views, metric (the summary key, e.g. masked_lpips), value (full precision; the paper's
    as printed), scenes (";"-separated, those the value averages), frames (how many test frames it averages, runs for
    the held-out error; blank for the paper's), std and runs (the standard deviation over a model's repeats and how
    many; blank without repeats). Cells without a value have no line."""
    out: list[dict[str, str | int]] = []
    for row in rows:
        for n in views:
            for metric in table_metrics(depth, heldout):
                for key in score_keys(metric, scores):
                    if (n, key) in row.values:
                        value = row.printed.get((n, key), repr(row.values[(n, key)]))
                        out.append({"table": table, "model": row.model, "source": "paper" if row.paper else "measured",
                                    "n_views": n, "metric": key, "value": value,
                                    "scenes": ";".join(row.scenes.get(n, ())), "frames": row.frames.get((n, key), ""),
                                    "std": repr(row.spread[(n, key)]) if (n, key) in row.spread else "",
                                    "runs": row.runs[n] if (n, key) in row.spread else ""})
    return out


def write_csv(path: Path, lines: Sequence[dict[str, str | int]]) -> None:
    """Writes `csv_rows` output with a header line."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows(lines)
