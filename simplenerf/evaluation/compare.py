"""Side-by-side test metrics of several runs (their `test/summary.json`), as a markdown table."""

from __future__ import annotations

import json
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


def markdown_table(summaries: dict[str, dict]) -> str:
    """One row per run, one column per metric (arrows say which way is better)."""
    metrics = [m for m in (*ALL_METRICS, *HELDOUT) if any(s.get(m) is not None for s in summaries.values())]
    arrow = {m: "↓" if m in LOWER_IS_BETTER else "↑" for m in metrics}
    lines = ["| run | " + " | ".join(f"{m} {arrow[m]}" for m in metrics) + " |",
             "|---|" + "---:|" * len(metrics)]
    for name, summary in summaries.items():
        cells = [f"{summary[m]:.4f}" if summary.get(m) is not None else "-" for m in metrics]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def seed_table(groups: dict[str, list[dict]]) -> str:
    """One row per model over several runs (e.g. seeds): each metric as mean ± sample standard deviation (n - 1 in
    the denominator; 0 for a single run), and the number of runs."""
    every = [s for summaries in groups.values() for s in summaries]
    metrics = [m for m in (*ALL_METRICS, *HELDOUT) if any(s.get(m) is not None for s in every)]
    arrow = {m: "↓" if m in LOWER_IS_BETTER else "↑" for m in metrics}
    lines = ["| model | runs | " + " | ".join(f"{m} {arrow[m]}" for m in metrics) + " |",
             "|---|---:|" + "---:|" * len(metrics)]
    for name, summaries in groups.items():
        cells = []
        for m in metrics:
            values = [s[m] for s in summaries if s.get(m) is not None]
            if not values:
                cells.append("-")
                continue
            mean = sum(values) / len(values)
            var = sum((v - mean) ** 2 for v in values) / (len(values) - 1) if len(values) > 1 else 0.0
            cells.append(f"{mean:.4f} ± {var**0.5:.4f}")
        lines.append(f"| {name} | {len(summaries)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
