"""The figures of `benchmarks/speed/gpu.sh`: one JSON line per step in `<out>/results.jsonl`, and `<out>/summary.md`.

    python -m benchmarks.speed.gpu_report record OUT STEP STATUS WALL_S [--from-json FILE] [--test-summary FILE]
                                           [--checkpoint FILE] [--note TEXT]
    python -m benchmarks.speed.gpu_report summary OUT

`record` appends one line: the step's name, exit status (0 done, 124 its time limit, "skipped"), wall seconds, and
what the step measured: the last JSON line of `--from-json` (`simplenerf benchmark`'s measurement, the
release-equivalence check's `--json`), the means of a test's `summary.json` (`--test-summary`), the global step of a
fit's checkpoint (`--checkpoint`). `summary` writes the short table of all lines to `<out>/summary.md` and prints it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RESULTS = "results.jsonl"
TEST_KEYS = ("frames", "psnr", "ssim", "lpips", "depth_mae", "depth_srocc")


def last_json_line(path: Path) -> dict | None:
    """The last line of `path` that is a JSON object, or None (a step that failed before printing one)."""
    if not path.is_file():
        return None
    for line in reversed(path.read_text().splitlines()):
        try:
            value = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(value, dict):
            return value
    return None


def checkpoint_step(path: Path) -> int | None:
    """The `global_step` a Lightning checkpoint was written at (the steps a fit reached), or None without one."""
    if not path.is_file():
        return None
    import torch

    return int(torch.load(path, map_location="cpu", weights_only=False)["global_step"])


def record(out: Path, step: str, status: str, wall_s: float, from_json: Path | None = None,
           test_summary: Path | None = None, checkpoint: Path | None = None, note: str = "") -> dict:
    line: dict = {"step": step, "status": int(status) if status.lstrip("-").isdigit() else status,
                  "wall_s": round(wall_s, 1)}
    if note:
        line["note"] = note
    if from_json is not None:
        line["measured"] = last_json_line(from_json)
    if test_summary is not None and test_summary.is_file():
        summary = json.loads(test_summary.read_text())
        line["test"] = {k: summary.get(k) for k in TEST_KEYS}
    if checkpoint is not None:
        line["global_step"] = checkpoint_step(checkpoint)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / RESULTS, "a") as f:
        f.write(json.dumps(line) + "\n")
    return line


def _num(value, fmt: str) -> str:
    return "" if value is None else format(value, fmt)


def summary(out: Path) -> str:
    """A markdown summary of `<out>/results.jsonl`: the machine, then one row per step."""
    lines = [json.loads(x) for x in (out / RESULTS).read_text().splitlines() if x.strip()]
    text = []
    for line in lines:
        if line["step"] == "machine":
            m = line["measured"] or {}
            text.append(f"GPU: {m.get('gpu')}, {_num(m.get('memory_gib'), '.0f')} GiB; driver {m.get('driver')}; "
                        f"torch {m.get('torch')}, CUDA {m.get('cuda')}; commit {m.get('commit')}; {m.get('date')}")
    text += ["", "| step | status | wall s | s/it median (min-max) | peak GPU GiB (reserved) | result |",
             "|---|---|---:|---|---|---|"]
    for line in lines:
        if line["step"] == "machine":
            continue
        m = line.get("measured") or {}
        per_it = peak = result = ""
        if "s_per_it" in m:
            per_it = f"{m['s_per_it']:.3f} ({m['s_per_it_min']:.3f}-{m['s_per_it_max']:.3f})"
            if m.get("peak_cuda_gib") is not None:  # None: measured without CUDA
                peak = f"{m['peak_cuda_gib']:.2f} ({_num(m.get('peak_cuda_reserved_gib'), '.2f')})"
            result = f"{m.get('rays_per_s', 0):.0f} rays/s"
        elif m.get("check") == "release_equivalence":
            result = f"{m['passed_rows']} of {m['rows']} rows pass on {m['device_name']}"
            if m["failed"]:
                result += "; FAIL: " + "; ".join(m["failed"][:5]) + (" ..." if len(m["failed"]) > 5 else "")
        if line.get("global_step") is not None:
            result = f"reached step {line['global_step']}"
        if "test" in line:
            t = line["test"]
            result = (f"{t['frames']} frames: PSNR {_num(t['psnr'], '.2f')}, SSIM {_num(t['ssim'], '.3f')}, "
                      f"LPIPS {_num(t['lpips'], '.3f')}, depth MAE {_num(t['depth_mae'], '.3f')}")
        if line.get("note"):
            result = f"{result}; {line['note']}" if result else line["note"]
        status = {0: "done", 124: "time limit"}.get(line["status"], str(line["status"]))
        text.append(f"| {line['step']} | {status} | {line['wall_s']:.0f} | {per_it} | {peak} | {result} |")
    return "\n".join(text) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="append one step's JSON line to OUT/results.jsonl")
    rec.add_argument("out", type=Path)
    rec.add_argument("step")
    rec.add_argument("status", help="exit status, or skipped")
    rec.add_argument("wall_s", type=float)
    rec.add_argument("--from-json", type=Path, default=None)
    rec.add_argument("--test-summary", type=Path, default=None)
    rec.add_argument("--checkpoint", type=Path, default=None)
    rec.add_argument("--note", default="")
    summ = sub.add_parser("summary", help="write OUT/summary.md from OUT/results.jsonl and print it")
    summ.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    if args.command == "record":
        record(args.out, args.step, args.status, args.wall_s, args.from_json, args.test_summary, args.checkpoint,
               args.note)
        return 0
    if not (args.out / RESULTS).is_file():
        print(f"gpu_report: {args.out / RESULTS} does not exist: no step was recorded", file=sys.stderr)
        return 2
    text = summary(args.out)
    (args.out / "summary.md").write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
