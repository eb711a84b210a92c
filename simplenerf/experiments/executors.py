"""Runs a plan's units with submitit (no scheduler of our own): what is done is skipped, the rest is submitted.

- `slurm`: one job array per stage (`SlurmExecutor.map_array`), each with `afterok` dependencies on the arrays whose
  outputs it reads (the table: `afterany`, it shows whatever was tested) and `--kill-on-invalid-dep=yes`, so a failed
  job cancels what needs it instead of leaving it pending; run the sweep again to retry. The array's `%N` is
  `resources.concurrent_jobs`. `--signal=USR1@90` is Lightning's requeue signal (`SLURMEnvironment(auto_requeue=True)`,
  see `simplenerf.experiments.jobs`); submitit's own preemption signal (USR2) is never sent, so only Lightning requeues.
  `--dry-run` writes the same arrays as self-contained sbatch scripts plus `submit.sh` instead (`write_slurm_scripts`).
- `local`: the same graph on this machine, each job once the jobs it needs are done, `resources.concurrent_jobs`
  submitit `LocalExecutor` jobs (processes) at a time.
- `debug`: the same, in this process, one job after the other (submitit's `DebugExecutor`).

A unit runs when it is not done (`is_done`) or something it needs runs; locally a unit whose needs did not finish is
skipped ("blocked"). The plan is written to `<sweep>/sweep.json` first: `sweep status` reads it and the units' state
files.
"""

from __future__ import annotations

import json
import shlex
import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path

from simplenerf.experiments.jobs import run_unit
from simplenerf.experiments.plan import STAGES, Plan, Unit
from simplenerf.experiments.spec import Resources
from simplenerf.experiments.state import read_state, read_status

MANIFEST = "sweep.json"
REQUEUE_SIGNAL = "USR1@90"  # Lightning's SLURMEnvironment requeue signal, 90 s before the time limit


def is_done(unit: Unit) -> bool:
    """Done with the same digest; a test also of the fit that is there now (a resumed, longer fit is tested again);
    the table never (it is rewritten after every sweep)."""
    if unit.stage == "table":
        return False
    status, state = read_status(Path(unit.folder), unit.stage, unit.digest)
    if status != "done":
        return False
    if unit.stage == "test":
        fit = read_state(Path(unit.folder), "fit") or {}
        return state.get("fit_ended") == fit.get("ended")
    return True


def units_to_run(plan: Plan) -> list[Unit]:
    """The units that are not done, or need one that runs, in stage order."""
    runs: set[str] = set()
    for unit in plan.units:
        if not is_done(unit) or any(need in runs for need in unit.needs):
            runs.add(unit.id)
    return [u for u in plan.units if u.id in runs]


def write_manifest(plan: Plan) -> Path:
    plan.output.mkdir(parents=True, exist_ok=True)
    path = plan.output / MANIFEST
    path.write_text(json.dumps({"name": plan.sweep.name, "units": [u.to_dict() for u in plan.units]}, indent=1))
    return path


def read_manifest(folder: Path) -> tuple[str, list[Unit]]:
    data = json.loads((Path(folder) / MANIFEST).read_text())
    return data["name"], [Unit.from_dict(u) for u in data["units"]]


def _quiet_run(unit: dict) -> str:
    """run_unit for the debug executor: failures are recorded in the state file, never raised (submitit's debug jobs
    open a debugger on an exception)."""
    try:
        return run_unit(unit, raise_on_failure=False)
    except Exception:
        return "failed"


def run_here(plan: Plan, todo: list[Unit], executor: str, log=print) -> dict[str, str]:
    """The local and debug executors: the plan's graph as SLURM runs it, each job once the jobs it needs are done,
    `concurrent_jobs` at a time (debug: one); returns unit id -> done / failed / blocked."""
    import submitit

    logs = plan.output / "logs"
    resources = plan.sweep.resources
    if executor == "debug":
        ex = submitit.DebugExecutor(folder=logs)
        workers = 1
    else:
        ex = submitit.LocalExecutor(folder=logs)
        # A local job is not cut by a time limit (a week); GPUs: the first gpus_per_job of this machine.
        ex.update_parameters(timeout_min=7 * 24 * 60, gpus_per_node=resources.gpus_per_job)
        workers = resources.concurrent_jobs
    lock = threading.Lock()
    slots = threading.Semaphore(workers)  # jobs running at once

    def one(unit: Unit) -> str:
        with lock:
            job = ex.submit(_quiet_run if executor == "debug" else run_unit, unit.to_dict())
        log(f"  {unit.stage} {unit.key}: started (job {job.job_id})")
        try:
            result = job.result()
        except Exception:  # the job's exception, or its process was killed
            result = "failed"
        if result != "done":
            state = read_state(Path(unit.folder), unit.stage) or {}
            log(f"  {unit.stage} {unit.key}: failed: {state.get('error') or 'the job process ended (killed?)'}")
        else:
            log(f"  {unit.stage} {unit.key}: done")
        return result

    futures: dict[str, Future] = {}

    def after_needs(unit: Unit) -> str:
        """As SLURM's afterok: the unit waits for the jobs it needs (the table: afterany), then for a free slot."""
        needs = [futures[n] for n in unit.needs if n in futures]
        wait(needs)
        failed = [n for n in unit.needs if n in futures and futures[n].result() != "done"]
        if failed and unit.stage != "table":
            log(f"  {unit.stage} {unit.key}: blocked ({failed[0]} did not finish)")
            return "blocked"
        with slots:
            return one(unit)

    log(f"{len(todo)} job(s), {workers} at a time, each once the jobs it needs are done")
    # One waiting thread per unit; `todo` is in stage order, so a unit's needs are submitted before it.
    with ThreadPoolExecutor(max_workers=max(1, len(todo))) as pool:
        for unit in todo:
            futures[unit.id] = pool.submit(after_needs, unit)
        outcome = {uid: future.result() for uid, future in futures.items()}
    return outcome


def slurm_parameters(resources: Resources, name: str, stage: str) -> dict:
    """The submitit SlurmExecutor parameters of one stage's array (`_make_sbatch_string`'s names). Jobs start in the
    folder the sweep was started from (`--chdir`), where the sweep file's relative paths and `resources.setup` hold."""
    params = {"job_name": f"{name}-{stage}", "time": resources.time_limit_min,
              "cpus_per_task": resources.cpus_per_job, "ntasks_per_node": 1, "nodes": 1,
              "array_parallelism": resources.concurrent_jobs, "setup": list(resources.setup),
              "stderr_to_stdout": True,
              "additional_parameters": {"signal": REQUEUE_SIGNAL, "kill-on-invalid-dep": "yes",
                                        "chdir": str(Path.cwd()), **resources.slurm_args}}
    if resources.gpus_per_job:
        params["gpus_per_node"] = resources.gpus_per_job
    if resources.partition:
        params["partition"] = resources.partition
    if resources.account:
        params["account"] = resources.account
    if resources.mem_gb:
        params["mem"] = f"{int(resources.mem_gb * 1024)}MB"
    return params


def _stage_needs(units: list[Unit], stage: str, submitted: set[str]) -> list[str]:
    """The stages whose submitted units the units of `stage` need."""
    ids = {n for u in units if u.stage == stage for n in u.needs if n in submitted}
    return [s for s in STAGES if any(i.startswith(s + ":") for i in ids)]


def submit_slurm(plan: Plan, todo: list[Unit], log=print) -> dict[str, str]:
    """One array per stage, with afterok dependencies; returns stage -> SLURM array job id."""
    import submitit

    submitted = {u.id for u in todo}
    ids: dict[str, str] = {}
    for stage in STAGES:
        units = [u for u in todo if u.stage == stage]
        if not units:
            continue
        ex = submitit.SlurmExecutor(folder=plan.output / "slurm" / "logs", max_num_timeout=0)
        params = slurm_parameters(plan.sweep.resources, plan.sweep.name, stage)
        needs = [ids[s] for s in _stage_needs(todo, stage, submitted) if s in ids]
        if needs:
            kind = "afterany" if stage == "table" else "afterok"
            params["additional_parameters"]["dependency"] = f"{kind}:" + ":".join(needs)
        ex.update_parameters(**params)
        jobs = ex.map_array(run_unit, [u.to_dict() for u in units])
        ids[stage] = str(jobs[0].job_id).split("_")[0]
        log(f"{stage}: array {ids[stage]} of {len(units)} job(s)" + (f", after {', '.join(needs)}" if needs else ""))
    return ids


def write_slurm_scripts(plan: Plan, todo: list[Unit]) -> list[Path]:
    """`--dry-run --executor slurm`: per stage `<sweep>/slurm/<stage>.sbatch` (the array submitit would submit, its
    command `simplenerf sweep job` running unit $SLURM_ARRAY_TASK_ID of `<stage>.json`) and `submit.sh`, which submits
    them in order with their dependencies. Nothing is submitted."""
    from submitit.slurm.slurm import _make_sbatch_string

    folder = plan.output / "slurm"
    folder.mkdir(parents=True, exist_ok=True)
    submitted = {u.id for u in todo}
    written = []
    lines = ["#!/bin/bash",
             f"# Submits the sweep {plan.sweep.name}: one SLURM job array per stage, each after the arrays it reads "
             "(afterok; the table afterany).",
             "# Written by `python -m simplenerf sweep --dry-run --executor slurm`; submit with `bash submit.sh` (from "
             "any folder).", "set -euo pipefail"]
    python = shlex.quote(sys.executable)
    for stage in STAGES:
        units = [u for u in todo if u.stage == stage]
        if not units:
            continue
        (folder / f"{stage}.json").write_text(json.dumps([u.to_dict() for u in units], indent=1))
        command = (f"{python} -u -m simplenerf sweep job {shlex.quote(str(plan.output))} {stage} "
                   "${SLURM_ARRAY_TASK_ID}")
        text = _make_sbatch_string(command=command, folder=folder / "logs", map_count=len(units),
                                   **slurm_parameters(plan.sweep.resources, plan.sweep.name, stage))
        path = folder / f"{stage}.sbatch"
        path.write_text(text)
        written.append(path)
        needs = _stage_needs(todo, stage, submitted)
        dependency = ""
        if needs:
            kind = "afterany" if stage == "table" else "afterok"
            dependency = f" --dependency={kind}:" + ":".join(f"${{{s}%%;*}}" for s in needs)
        lines.append(f"{stage}=$(sbatch --parsable{dependency} {shlex.quote(str(path))})")
        lines.append(f'echo "{stage}: job array ${{{stage}%%;*}} ({len(units)} jobs)"')
    script = folder / "submit.sh"
    script.write_text("\n".join(lines) + "\n")
    script.chmod(0o755)
    return [*written, script]
