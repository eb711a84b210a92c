"""`simplenerf sweep status SWEEP_DIR`: every job of a sweep, read from its folders (the plan in `<sweep>/sweep.json`,
each job's `<folder>/.sweep/<stage>.json`), no database: stage, scene, views, model, seed, status (pending, running,
stopped: its process is gone, done, failed with its error line), training steps done and wall time. For a sweep
submitted to SLURM, SLURM's own word where the job's files cannot have it (`simplenerf.experiments.slurm`): queued
(with squeue's reason), and how a task ended that its job could not record: cancelled, timeout, out_of_memory,
node_fail, ... with the job id."""

from __future__ import annotations

from pathlib import Path

from simplenerf.experiments.executors import MANIFEST, is_done, read_manifest
from simplenerf.experiments.slurm import ENDED_BADLY, slurm_states, submitted_jobs
from simplenerf.experiments.spec import SweepError
from simplenerf.experiments.state import checkpoint_steps, read_status, wall_time

COLUMNS = ("stage", "scene", "views", "model", "seed", "status", "steps", "wall", "job", "error")


def _wall(seconds: float | None) -> str:
    if not seconds:
        return ""
    s = int(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def status_rows(folder: Path) -> list[dict[str, str]]:
    if not (Path(folder) / MANIFEST).is_file():
        raise SweepError(f"{folder} is not a sweep folder (no {MANIFEST}; `simplenerf sweep --config FILE` writes it)")
    _, units = read_manifest(Path(folder))
    jobs = submitted_jobs(Path(folder))
    slurm = slurm_states(list(jobs.values())) if jobs else None
    rows = []
    for unit in units:
        status, state = read_status(Path(unit.folder), unit.stage, unit.digest)
        if status == "done" and not is_done(unit) and unit.stage == "test":
            status = "pending"  # tested an earlier fit; the fit has changed since
        state = state or {}
        steps = ""
        if unit.stage in ("fit", "dense") and status != "pending":
            total = state.get("max_steps")
            # a done fit reached max_steps: no need to open its last.ckpt for the step (checkpoint_steps would)
            done = total if status == "done" and total else checkpoint_steps(Path(unit.folder))
            steps = f"{done or 0}/{total}" if total else str(done or 0)
        rows.append({"stage": unit.stage, "scene": unit.labels.get("scene", ""), "views": unit.labels.get("views", ""),
                     "model": unit.labels.get("model", ""), "seed": unit.labels.get("seed", ""), "status": status,
                     "steps": steps,
                     "wall": _wall(wall_time(status, state, Path(unit.folder))) if status != "pending" else "",
                     "job": str(state.get("job_id") or "") if status != "pending" else "",
                     "error": (state.get("error") or "") if status in ("failed", "stopped") else ""})
        job = jobs.get(unit.id)
        said = slurm.get(job) if slurm and job else None
        if said is not None and status != "done":
            _slurm_row(rows[-1], said, job, status)
    return rows


def _slurm_row(row: dict[str, str], said, job: str, status: str) -> None:
    """A row of a unit that is not done, with SLURM's state of its task."""
    if said.state in ("PENDING", "REQUEUED"):
        row.update(status="queued", job=job, error=f"SLURM: {said.state} ({said.detail})" if said.detail else "")
    elif said.state == "RUNNING":
        row.update(status="running", job=job)
    elif said.state in ENDED_BADLY:
        own = f"; {row['error']}" if row["error"] else ""
        row.update(status=said.state.lower(), job=job, error=f"SLURM: {said.state}"
                   + (f", {said.detail}" if said.detail else "") + own)


def status_table(folder: Path) -> str:
    """A markdown table of every job, then the count per status."""
    rows = status_rows(folder)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for row in rows:
        lines.append("| " + " | ".join(row[c].replace("|", "\\|") for c in COLUMNS) + " |")
    counts: dict[str, int] = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    lines += ["", f"{len(rows)} jobs: " + ", ".join(f"{n} {s}" for s, n in counts.items())]
    return "\n".join(lines)
