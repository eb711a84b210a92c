"""Markdown table of a side-by-side sitting: the release's driver.py JSON files and our `simplenerf benchmark` JSON
lines.

    python -m benchmarks.speed.summarize results/side_by_side/*.json

Per variant (our runs carry it as `label`) and our precision: pooled s/it of the release (its discarded warm-up
iterations and short sparse-depth batches left out, as ../shared/tools/official_timing/summarize.py) and of ours
(timed iterations after warm-up), the ratio release / ours (above 1: ours is faster) and each side's peak RSS. The
table starts with the machine our records name (CPU model and capability, GPU): records of different machines are
refused, so that no ratio mixes CPUs (the release's JSON does not name its machine: it ran in the same sitting).
"""

from __future__ import annotations

import json
import statistics
import sys
from collections.abc import Iterable
from pathlib import Path


def _load_records(paths: Iterable[str | Path]) -> tuple[list[dict], list[dict]]:
    """(release summaries, our train_step records) from driver.py JSON files and train_step JSON-line files."""
    release, ours = [], []
    for path in paths:
        text = Path(path).read_text().strip()
        if not text:
            continue
        try:
            items = [json.loads(text)]
        except json.JSONDecodeError:  # JSON lines
            items = [json.loads(line) for line in text.splitlines() if line.strip().startswith("{")]
        for item in items:
            if item.get("benchmark") == "train_step":
                ours.append(item)
            elif "records" in item and "variant" in item:
                release.append(item)
    return release, ours


def release_iterations(summary: dict) -> list[dict]:
    """The timed iterations of one driver.py run: after its discarded ones, full batches only (as summarize.py)."""
    want = (summary["rays_rgb"], summary["rays_sd"])
    return [r for r in summary["records"][summary["discarded"] :] if (r["rays_rgb"], r["rays_sd"]) == want]


def _cell(values: list[float]) -> str:
    if not values:
        return "-"
    return f"{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f}, n={len(values)})"


def side_by_side_table(paths: Iterable[str | Path]) -> str:
    """Markdown table: per variant (and our precision), the pooled s/it of the release and ours, their ratio
    (release / ours: above 1 means ours is faster), the median CPU seconds (user + system) per iteration of each,
    which a shared machine disturbs less than wall time, and the peak RSS of each (range over runs)."""
    release, ours = _load_records(paths)
    machine = machine_line(ours)
    release_by: dict[str, list[dict]] = {}
    for s in release:
        release_by.setdefault(s["variant"], []).append(s)
    ours_by: dict[tuple[str, str], list[dict]] = {}
    for r in ours:
        ours_by.setdefault((r.get("label") or "?", r["precision"] + (" +tf32" if r.get("tf32") else "")), []).append(r)
    keys = sorted(set(ours_by) | {(v, "32-true") for v in release_by if not any(k[0] == v for k in ours_by)})
    lines = [
        machine,
        "",
        "| variant | rays/it | ours precision | release s/it median (min-max, n) | ours s/it median (min-max, n) "
        "| release / ours | CPU s/it release / ours | release peak RSS GiB | ours peak RSS GiB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for variant, precision in keys:
        rel = release_by.get(variant, [])
        own = ours_by.get((variant, precision), [])
        rel_s = [r["seconds"] for run in rel for r in release_iterations(run)]
        own_s = [s for run in own for s in run["s_per_it_all"]]
        ratio = f"{statistics.median(rel_s) / statistics.median(own_s):.2f}" if rel_s and own_s else "-"
        rel_cpu = [r["user_s"] + r["sys_s"] for run in rel for r in release_iterations(run) if "user_s" in r]
        own_cpu = [s for run in own for s in run.get("cpu_s_all", [])]
        cpu = " / ".join(f"{statistics.median(v):.2f}" if v else "-" for v in (rel_cpu, own_cpu))
        rays = (f"{rel[0]['rays_rgb']}+{rel[0]['rays_sd']}" if rel else
                f"{own[0]['rays_random']}+{own[0]['rays_sparse']}" if own else "?")
        rel_rss = [run["peak_rss_mib"] / 1024 for run in rel]
        own_rss = [run["peak_rss_gib"] for run in own]
        lines.append(f"| {variant} | {rays} | {precision} | {_cell(rel_s)} | {_cell(own_s)} | {ratio} | {cpu} "
                     f"| {_range(rel_rss)} | {_range(own_rss)} |")
    return "\n".join(lines)


def machine_line(records: list[dict]) -> str:
    """`Machine: <CPU model> (<capability>)[, GPU <model>]` of our records (`simplenerf benchmark`'s JSON); one
    machine only (records written before the JSON named the CPU: `unknown`)."""
    machines = {(r.get("cpu") or "unknown CPU", r.get("cpu_capability") or "capability unknown", r.get("gpu"))
                for r in records}
    if len(machines) > 1:
        names = "; ".join(sorted(f"{cpu} ({capability})" + (f", GPU {gpu}" if gpu else "")
                                 for cpu, capability, gpu in machines))
        raise ValueError(f"summarize: the records come from different machines ({names}): one sitting at a time")
    cpu, capability, gpu = machines.pop() if machines else ("unknown CPU", "capability unknown", None)
    return f"Machine: {cpu} ({capability})" + (f", GPU {gpu}" if gpu else "")


def _range(values: list[float]) -> str:
    if not values:
        return "-"
    low, high = min(values), max(values)
    return f"{low:.2f}" if abs(high - low) < 0.005 else f"{low:.2f}-{high:.2f}"


def main() -> None:
    if sys.argv[1:2] in (["-h"], ["--help"]):
        print(__doc__)
        return
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print(side_by_side_table(sys.argv[1:]))


if __name__ == "__main__":
    main()
