"""Side-by-side test metrics of several runs (their `test/summary.json`), as a markdown table."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

from simplenerf.evaluation.evaluator import ALL_METRICS

# Depth error at held-out SfM points (tools/heldout_depth_error.py --out <run>/heldout_depth.json), for real scenes
# without a reference depth.
HELDOUT = {"heldout_rel_error_mean": "rel_error_mean", "heldout_rel_error_median": "rel_error_median"}
LOWER_IS_BETTER = {"lpips", "depth_mae", "masked_lpips", "masked_depth_mae", *HELDOUT}


def load_summaries(runs: dict[str, Path]) -> dict[str, dict]:
    """Run name -> the summary.json of its test outputs (a run folder or its test/ folder), plus the held-out SfM
    depth error of `<run>/heldout_depth.json` where that file exists."""
    summaries = {}
    for name, path in runs.items():
        path = Path(path)
        file = path / "summary.json" if (path / "summary.json").is_file() else path / "test" / "summary.json"
        if not file.is_file():
            raise FileNotFoundError(f"{file} not found: run `python -m simplenerf test ...` for {name} first")
        summaries[name] = json.loads(file.read_text())
        heldout = file.parent.parent / "heldout_depth.json"
        if heldout.is_file():
            result = json.loads(heldout.read_text())
            summaries[name].update({key: result[field] for key, field in HELDOUT.items()})
    return summaries


def _header(first: list[str], every: list[dict]) -> tuple[list[str], list[str]]:
    """The metrics any of these summaries has, and the table's two header lines (arrows say which way is better)."""
    metrics = [m for m in (*ALL_METRICS, *HELDOUT) if any(s.get(m) is not None for s in every)]
    names = [f"{m} {'↓' if m in LOWER_IS_BETTER else '↑'}" for m in metrics]
    return metrics, ["| " + " | ".join(first + names) + " |", "|---|" + "---:|" * (len(first) - 1 + len(metrics))]


def markdown_table(summaries: dict[str, dict]) -> str:
    """One row per run, one column per metric."""
    metrics, lines = _header(["run"], list(summaries.values()))
    for name, summary in summaries.items():
        cells = [f"{summary[m]:.4f}" if summary.get(m) is not None else "-" for m in metrics]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def seed_table(groups: dict[str, list[dict]]) -> str:
    """One row per model over several runs (e.g. seeds): each metric as mean ± sample standard deviation
    (`statistics.stdev`; 0 for a single run), and the number of runs."""
    metrics, lines = _header(["model", "runs"], [s for summaries in groups.values() for s in summaries])
    for name, summaries in groups.items():
        cells = []
        for m in metrics:
            values = [s[m] for s in summaries if s.get(m) is not None]
            std = statistics.stdev(values) if len(values) > 1 else 0.0
            cells.append(f"{statistics.fmean(values):.4f} ± {std:.4f}" if values else "-")
        lines.append(f"| {name} | {len(summaries)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
