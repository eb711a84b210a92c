"""The sweep's results table: its tested runs in the layout of the paper's Tables 1-3 (`simplenerf.reporting.tables`,
the table of `simplenerf results`), beside the published rows of the table the sweep file names per scene format, in
the sweep's `scores` (masked, full or both), with the held-out SfM depth error where runs have it (`heldout_depth`),
written to `<sweep>/results.md` and `<sweep>/results.csv` (long format, one line per value).
"""

from __future__ import annotations

from pathlib import Path

from simplenerf.experiments.state import checkpoint_steps, process_alive, read_state
from simplenerf.reporting.records import HELDOUT_KEYS, coverage_warnings, load_records, mean_rows
from simplenerf.reporting.tables import (
    caption,
    csv_rows,
    markdown_table,
    paper_rows,
    score_keys,
    table_metrics,
    table_views,
    write_csv,
)

FORMAT_TITLES = {"llff": "LLFF", "realestate": "RealEstate-10K"}


def write_results(out: Path, runs: list[list[str]], tables: dict[str, str], scores: str = "masked") -> list[Path]:
    """`runs`: [format, row name, run folder, key, masks folder] of every test of the sweep; those with a test summary
    make the table, every other gets a line with the reason (`missing_reason`). Returns the written files."""
    blocks, lines = [], []
    for fmt in dict.fromkeys(run[0] for run in runs):
        ours = [run for run in runs if run[0] == fmt]
        tested = [(run[1], Path(run[2])) for run in ours if (Path(run[2]) / "test" / "summary.json").is_file()]
        missing = [run for run in ours if not (Path(run[2]) / "test" / "summary.json").is_file()]
        paper = tables.get(fmt)
        records = load_records(tested)
        rows = (paper_rows(paper) if paper else []) + mean_rows(records)
        heldout = any(r.frames[k] for r in records for k in HELDOUT_KEYS)  # runs with heldout_depth.json
        keys = [k for m in table_metrics(True, heldout) for k in score_keys(m, scores)]
        views = table_views(rows, keys)
        blocks += [f"## {FORMAT_TITLES.get(fmt, fmt)}", caption(scores, False, paper, heldout=heldout),
                   markdown_table(rows, views, scores, depth=True, heldout=heldout)]
        notes = [f"- {w}" for w in coverage_warnings(records, keys)]
        if missing:
            notes.append(f"- {len(missing)} of {len(ours)} runs are not in the table (the means above are over the "
                         "others):")
            for run in missing:
                key = run[3] if len(run) > 3 else run[2]
                masks = Path(run[4]) if len(run) > 4 and run[4] else None  # none: `reference_depth: none`
                notes.append(f"  - {key}: {missing_reason(Path(run[2]), masks)}")
        if notes:
            blocks.append("\n".join(notes))
        lines += csv_rows(fmt if paper is None else f"{fmt} ({paper})", rows, views, scores, depth=True,
                          heldout=heldout)
    md, csv = out / "results.md", out / "results.csv"
    md.write_text("\n\n".join(["# Results", *blocks]) + "\n")
    write_csv(csv, lines)
    return [md, csv]


def _said(stage: str, state: dict | None, folder: Path) -> str | None:
    """A job's outcome from its state file, or None when it finished."""
    if state is None:
        return f"its {stage} never started"
    status = state.get("status")
    if status == "done":
        return None
    if status == "failed":
        return f"its {stage} failed: {state.get('error') or 'no error line recorded'}"
    if status == "running":
        alive = process_alive(state)
        if alive is False:
            at = f" at step {checkpoint_steps(folder) or 0}" if stage == "fit" else ""
            return f"its {stage} stopped{at} (its process ended without a word: killed, out of memory?)"
        return f"its {stage} is still running (job {state.get('job_id')}; `sweep status` asks SLURM)"
    return f"its {stage} is {status}"


def missing_reason(run: Path, masks: Path | None) -> str:
    """Why a run has no test results, from the state files of its test, fit and masks: the first job of its chain
    that did not finish, with its error line."""
    test = read_state(run, "test")
    if test is not None and test.get("status") != "done":
        return _said("test", test, run) or ""
    fit = _said("fit", read_state(run, "fit"), run)
    if fit is not None:
        return fit + "; its test did not run"
    if masks is not None:
        said = _said("masks", read_state(masks, "masks"), masks)
        if said is not None:
            return said + "; its test did not run"
    return "its test never started"
