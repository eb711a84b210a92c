"""What SLURM says about a submitted sweep (`sweep status`) and cancelling it (`sweep cancel`), through SLURM's own
commands: `squeue` (queued and running tasks), `sacct` (how finished tasks ended: CANCELLED, TIMEOUT, OUT_OF_MEMORY,
NODE_FAIL, ...) and `scancel`. A job killed by SLURM never updates its own state file (it says running for ever, or
nothing when it never started); these states come from SLURM.

The sweep's job ids: `<sweep>/slurm/arrays.json` (each array's units in task order, written by the dry run and by
the submission) and `<sweep>/slurm/submitted.txt` ("<array name> <job id>" per submitted array, written by
`submit.sh` or by the submission through submitit).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from simplenerf.experiments.spec import SweepError

ENDED_BADLY = ("CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL", "FAILED", "PREEMPTED", "BOOT_FAIL", "DEADLINE")
"""SLURM states of a task that ended without finishing; `sweep status` shows them (lower case) with the job id."""


@dataclass
class JobState:
    state: str
    """SLURM's state, e.g. PENDING, RUNNING, COMPLETED, TIMEOUT, OUT_OF_MEMORY (sacct's "CANCELLED by N": CANCELLED)."""
    detail: str = ""
    """squeue's reason (e.g. Dependency, Priority) or sacct's exit code."""


def submitted_jobs(folder: Path) -> dict[str, str]:
    """unit id -> SLURM job id of its task (`<array job>_<task>`), for the arrays that were submitted."""
    slurm = Path(folder) / "slurm"
    arrays_file, submitted_file = slurm / "arrays.json", slurm / "submitted.txt"
    if not arrays_file.is_file() or not submitted_file.is_file():
        return {}
    ids = dict(line.split()[:2] for line in submitted_file.read_text().splitlines() if len(line.split()) >= 2)
    jobs = {}
    for array in json.loads(arrays_file.read_text()):
        if array["name"] in ids:
            for task, unit in enumerate(array["units"]):
                jobs[unit] = f"{ids[array['name']]}_{task}"
    return jobs


def _run(command: list[str]) -> str:
    """stdout of a SLURM command; an error (e.g. squeue on a job id it no longer knows) gives what it printed."""
    proc = subprocess.run(command, capture_output=True, text=True, timeout=120)
    return proc.stdout


def _expand(job_id: str) -> list[str]:
    """`1001_[3-5,9%24]` (a pending array's remaining tasks) -> 1001_3, 1001_4, 1001_5, 1001_9; others as they are."""
    m = re.fullmatch(r"(\d+)_\[([^\]]+)\]", job_id)
    if not m:
        return [job_id]
    out = []
    for part in m.group(2).split("%")[0].split(","):
        low, _, high = part.partition("-")
        out += [f"{m.group(1)}_{t}" for t in range(int(low), int(high or low) + 1)]
    return out


def slurm_states(job_ids: list[str]) -> dict[str, JobState] | None:
    """SLURM's state of every task in `job_ids` that it knows: sacct's for what ended, squeue's (newer) for what is
    queued or running. None when neither command is on PATH (not a SLURM machine)."""
    arrays = sorted({j.split("_")[0] for j in job_ids})
    if not arrays or not (shutil.which("squeue") or shutil.which("sacct")):
        return None
    states: dict[str, JobState] = {}
    if shutil.which("sacct"):
        out = _run(["sacct", "-n", "-P", "-X", "-j", ",".join(arrays), "-o", "JobID,State,ExitCode"])
        for line in out.splitlines():
            parts = line.strip().split("|")
            if len(parts) >= 2 and parts[0]:
                for j in _expand(parts[0]):
                    states[j] = JobState(parts[1].split()[0] if parts[1].strip() else "", f"exit {parts[2]}"
                                         if len(parts) > 2 and parts[2] else "")
    if shutil.which("squeue"):
        out = _run(["squeue", "-h", "-r", "-j", ",".join(arrays), "-o", "%i|%T|%r"])
        for line in out.splitlines():
            parts = line.strip().split("|")
            if len(parts) >= 2 and parts[0]:
                for j in _expand(parts[0]):
                    states[j] = JobState(parts[1], parts[2] if len(parts) > 2 and parts[2] != "None" else "")
    return states


def cancel(folder: Path, log=print) -> list[str]:
    """`scancel` on every array of the sweep's last submission that SLURM still has queued or running (all of them
    when there is no squeue); returns the cancelled array ids. SweepError if the sweep was not submitted to SLURM."""
    submitted = Path(folder) / "slurm" / "submitted.txt"
    if not submitted.is_file():
        raise SweepError(f"{folder}: no slurm/submitted.txt, so nothing was submitted to SLURM from it (a local sweep "
                         "stops with Ctrl-C in its terminal)")
    arrays = [line.split()[1] for line in submitted.read_text().splitlines() if len(line.split()) >= 2]
    if not shutil.which("scancel"):
        raise SweepError("scancel is not on PATH: run `sweep cancel` on the cluster's login node")
    live = arrays
    if shutil.which("squeue"):
        states = slurm_states([f"{a}_0" for a in arrays]) or {}
        live_arrays = {j.split("_")[0] for j, s in states.items() if s.state in ("PENDING", "RUNNING", "REQUEUED",
                                                                              "CONFIGURING", "SUSPENDED")}
        live = [a for a in arrays if a in live_arrays]
    if not live:
        log(f"nothing of {folder} is queued or running ({len(arrays)} arrays submitted)")
        return []
    proc = subprocess.run(["scancel", *live], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        raise SweepError(f"scancel {' '.join(live)} failed: {proc.stderr.strip() or f'exit status {proc.returncode}'}")
    log(f"cancelled {len(live)} of {len(arrays)} job arrays: {' '.join(live)}; the same `sweep` command resubmits "
        "what is not done")
    return live
