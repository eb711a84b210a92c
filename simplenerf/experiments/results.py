"""The sweep's results table: its tested runs in the layout of the paper's Tables 1-3 (`simplenerf.reporting.tables`,
the table of `simplenerf results`), beside the published rows of the table the sweep file names per scene format,
written to `<sweep>/results.md` and `<sweep>/results.csv` (long format, one line per value).
"""

from __future__ import annotations

from pathlib import Path

from simplenerf.reporting.records import coverage_warnings, load_records, mean_rows
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
    """`runs`: [format, row name, run folder] of every test of the sweep; those with a test summary make the table.
    Returns the written files."""
    blocks, lines = [], []
    for fmt in dict.fromkeys(f for f, _, _ in runs):
        ours = [(row, Path(folder)) for f, row, folder in runs if f == fmt]
        tested = [(row, folder) for row, folder in ours if (folder / "test" / "summary.json").is_file()]
        missing = [str(folder) for row, folder in ours if not (folder / "test" / "summary.json").is_file()]
        paper = tables.get(fmt)
        records = load_records(tested)
        rows = (paper_rows(paper) if paper else []) + mean_rows(records)
        keys = [k for m in table_metrics(True) for k in score_keys(m, scores)]
        views = table_views(rows, keys)
        blocks += [f"## {FORMAT_TITLES.get(fmt, fmt)}", caption(scores, False, paper),
                   markdown_table(rows, views, scores, depth=True)]
        notes = [f"- {w}" for w in coverage_warnings(records, keys)]
        if missing:
            notes.append(f"- {len(missing)} of {len(missing) + len(tested)} runs have no test results yet: "
                         + ", ".join(missing))
        if notes:
            blocks.append("\n".join(notes))
        lines += csv_rows(fmt if paper is None else f"{fmt} ({paper})", rows, views, scores, depth=True)
    md, csv = out / "results.md", out / "results.csv"
    md.write_text("\n\n".join(["# Results", *blocks]) + "\n")
    write_csv(csv, lines)
    return [md, csv]
