"""A job's state, kept in its own folder (no database): `<folder>/.sweep/<stage>.json`.

Fields: stage, key, digest (of what the job computes, `plan.Unit.digest`), status (running / done / failed),
started, ended (ISO times of the last attempt), wall_s (seconds over all attempts), attempts, host, pid, job_id
(SLURM's, `<array>_<task>` in an array; the local process's), error (the failure's one line), steps (training steps
done, read from the checkpoints: `checkpoint_steps`), and for a test the `fit_ended` of the fit it scored.

A job whose process is gone while its state says running (killed, out of memory, the machine rebooted) shows as
`stopped`; the next sweep resumes it. `read_status` gives the status the status table shows.
"""

from __future__ import annotations

import json
import os
import re
import socket
import time
from datetime import datetime, timezone
from pathlib import Path

STATE_DIR = ".sweep"


def state_path(folder: Path, stage: str) -> Path:
    return Path(folder) / STATE_DIR / f"{stage}.json"


def read_state(folder: Path, stage: str) -> dict | None:
    path = state_path(folder, stage)
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def write_state(folder: Path, stage: str, state: dict) -> None:
    path = state_path(folder, stage)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(state, indent=2))
    tmp.replace(path)  # atomic: a reader never sees half a file


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def job_id() -> str:
    """SLURM's id of this job (`<array job>_<task>` in an array), else this process's id."""
    array = os.environ.get("SLURM_ARRAY_JOB_ID")
    if array is not None:
        return f"{array}_{os.environ.get('SLURM_ARRAY_TASK_ID')}"
    return os.environ.get("SLURM_JOB_ID") or f"pid {os.getpid()}"


def checkpoint_steps(folder: Path) -> int | None:
    """The highest step among a run's checkpoints: the periodic ones by name (`checkpoints/step000500.ckpt`), and
    `checkpoints/last.ckpt` by its `global_step` (a fit stopped by a signal saves there at the step it reached, between
    periodic ones; read memory-mapped, without its tensors). None without one. (`hpc_ckpt_N.ckpt`, SLURM's requeue
    checkpoint in the run's folder, has no step in its name and is not read.)"""
    checkpoints = Path(folder) / "checkpoints"
    steps = [int(m.group(1)) for p in checkpoints.glob("step*.ckpt") if (m := re.fullmatch(r"step(\d+)\.ckpt", p.name))]
    if (last := _saved_step(checkpoints / "last.ckpt")) is not None:
        steps.append(last)
    return max(steps) if steps else None


def _saved_step(path: Path) -> int | None:
    """`global_step` of a Lightning checkpoint, None if there is none or it cannot be read (being written, damaged)."""
    from simplenerf.errors import CheckpointError
    from simplenerf.run.checks import read_checkpoint

    try:
        return int(read_checkpoint(path, mmap=True).get("global_step", 0))
    except CheckpointError:
        return None


def process_alive(state: dict) -> bool | None:
    """Whether the process of a running state still runs: True / False on this host, None elsewhere (unknown)."""
    if state.get("host") != socket.gethostname():
        return None
    try:
        os.kill(int(state.get("pid", -1)), 0)
    except (OSError, ValueError):
        return False
    return True


def read_status(folder: Path, stage: str, digest: str) -> tuple[str, dict | None]:
    """(status, state) of a unit: pending (no state, or one of an older digest), running, stopped (its process is gone
    on this host), done or failed."""
    state = read_state(folder, stage)
    if state is None or state.get("digest") != digest:
        return "pending", state
    status = state.get("status", "pending")
    if status == "running" and process_alive(state) is False:
        return "stopped", state
    return status, state


def wall_time(status: str, state: dict, folder: Path) -> float:
    """Seconds over all attempts; a running attempt counts until now, a stopped one until its newest file."""
    seconds = float(state.get("wall_s") or 0.0)
    if status in ("running", "stopped") and state.get("started"):
        started = datetime.fromisoformat(state["started"]).timestamp()
        if status == "running":
            end = time.time()
        else:
            files = [p.stat().st_mtime for p in folder.rglob("*") if p.is_file() and STATE_DIR not in p.parts]
            end = max(files, default=started)
        seconds += max(0.0, end - started)
    return seconds
