"""Runs a plan's units with submitit (no scheduler of our own): what is done is skipped, the rest is submitted.

- `slurm`: job arrays (`SlurmExecutor.map_array`, `slurm_arrays`) with per-task dependencies: a job waits for the
  tasks whose outputs it reads and nothing else (`aftercorr` where two arrays line up task for task,
  `afterok:<array>_<task>` otherwise; the table `afterany`, it shows whatever was tested), with
  `--kill-on-invalid-dep=yes`, so a failed job cancels only what reads its output; run the sweep again to retry. Each
  stage asks for its own resources (`Resources.for_stage`: the masks and the table no GPU); an array's `%N` is its
  stage's `concurrent_jobs`. `--signal=USR1@90` is Lightning's requeue signal (`SLURMEnvironment(auto_requeue=True)`,
  see `simplenerf.experiments.jobs`); submitit's own preemption signal (USR2) is never sent, so only Lightning requeues.
  `--dry_run` writes the same arrays as self-contained sbatch scripts plus `submit.sh` instead (`write_slurm_scripts`).
- `local`: the same graph on this machine, each job once the jobs it needs are done, `resources.concurrent_jobs`
  submitit `LocalExecutor` jobs (processes) at a time, each job of a GPU stage on GPUs of its own (`GpuPool`).
- `debug`: the same, in this process, one job after the other (submitit's `DebugExecutor`).

A unit runs when it is not done (`is_done`) or something it needs runs; locally a unit whose needs did not finish is
skipped ("blocked"). The plan is written to `<sweep>/sweep.json` first: `sweep status` reads it and the units' state
files.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from simplenerf.experiments.jobs import run_unit
from simplenerf.experiments.plan import Plan, Unit
from simplenerf.experiments.slots import ReadySlots
from simplenerf.experiments.spec import STAGES, Resources, SweepError
from simplenerf.experiments.state import read_state, read_status

MANIFEST = "sweep.json"
ARRAYS = "arrays.json"  # <sweep>/slurm/: the arrays of the last submission or dry run
SUBMITTED = "submitted.txt"  # <sweep>/slurm/: "<array name> <SLURM job id>" per submitted array
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


def visible_gpus() -> list[int]:
    """This machine's GPUs a local sweep hands out: CUDA_VISIBLE_DEVICES when it is set (integer ids), else every
    device torch sees."""
    env = os.environ.get("CUDA_VISIBLE_DEVICES")
    if env is not None and env.strip():
        try:
            return [int(x) for x in env.split(",") if x.strip()]
        except ValueError:
            raise SweepError(f"CUDA_VISIBLE_DEVICES={env}: a local sweep hands out GPUs by integer id; give ids, "
                             "not UUIDs") from None
    import torch

    return list(range(torch.cuda.device_count()))


class GpuPool:
    """The local executor's GPUs: a job takes `n` free ones (waiting until they are free) and gives them back, so
    that jobs running at the same time never share one (submitit's LocalExecutor sets the job's
    CUDA_VISIBLE_DEVICES to them)."""

    def __init__(self, gpus: list[int]) -> None:
        self.free, self.all = list(gpus), list(gpus)
        self.cond = threading.Condition()

    def take(self, n: int) -> list[int]:
        with self.cond:
            self.cond.wait_for(lambda: len(self.free) >= n)
            taken, self.free = self.free[:n], self.free[n:]
            return taken

    def give(self, gpus: list[int]) -> None:
        with self.cond:
            self.free += gpus
            self.cond.notify_all()


def run_here(plan: Plan, todo: list[Unit], executor: str, log=print, job_function=None) -> dict[str, str]:
    """The local and debug executors: the plan's graph as SLURM runs it, each job once the jobs it needs are done,
    `concurrent_jobs` at a time (debug: one); returns unit id -> done / failed / blocked. Locally, a job of a stage
    with `gpus_per_job` GPUs gets that many of this machine's GPUs of its own (`visible_gpus`, CUDA_VISIBLE_DEVICES);
    on a machine without a GPU every job runs on the CPU. `job_function` (tests): what each job runs instead of
    `run_unit`."""
    import submitit

    logs = plan.output / "logs"
    resources = plan.sweep.resources
    gpus = GpuPool([])
    if executor == "debug":
        ex = submitit.DebugExecutor(folder=logs)
        workers = 1
    else:
        ex = submitit.LocalExecutor(folder=logs)
        ex.update_parameters(timeout_min=7 * 24 * 60)  # a local job is not cut by a time limit (a week)
        workers = resources.concurrent_jobs
        gpus = GpuPool(visible_gpus())
        for stage in dict.fromkeys(u.stage for u in todo):
            wanted = resources.for_stage(stage).gpus_per_job
            if gpus.all and wanted > len(gpus.all):
                raise SweepError(f"resources: the {stage} jobs ask for {wanted} GPUs each; this machine has "
                                 f"{len(gpus.all)} ({', '.join(map(str, gpus.all))})")
        if not gpus.all and any(resources.for_stage(u.stage).gpus_per_job for u in todo):
            log("no GPU on this machine: every job runs on the CPU")
    function = job_function or (_quiet_run if executor == "debug" else run_unit)
    lock = threading.Lock()
    slots = ReadySlots(workers)  # jobs running at once, in the order they became ready

    def one(unit: Unit) -> str:
        wanted = resources.for_stage(unit.stage).gpus_per_job if gpus.all else 0
        mine = gpus.take(wanted) if wanted else []
        try:
            return _one(unit, mine)
        finally:
            gpus.give(mine)

    def _one(unit: Unit, mine: list[int]) -> str:
        with lock:
            if executor != "debug":
                ex.update_parameters(gpus_per_node=len(mine), visible_gpus=mine)
            job = ex.submit(function, unit.to_dict())
        log(f"  {unit.stage} {unit.key}: started (job {job.job_id}" + (f", GPU {','.join(map(str, mine))}"
                                                                      if mine else "") + ")")
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
    order = {unit.id: i for i, unit in enumerate(todo)}

    def after_needs(unit: Unit) -> str:
        """As SLURM's afterok: the unit waits for the jobs it needs (the table: afterany), then for a free slot."""
        needs = [futures[n] for n in unit.needs if n in futures]
        wait(needs)
        failed = [n for n in unit.needs if n in futures and futures[n].result() != "done"]
        if failed and unit.stage != "table":
            log(f"  {unit.stage} {unit.key}: blocked ({failed[0]} did not finish)")
            return "blocked"
        with slots.slot(order[unit.id]):
            return one(unit)

    log(f"{len(todo)} job(s), {workers} at a time, each once the jobs it needs are done")
    # One waiting thread per unit; `todo` is in stage order, so a unit's needs are submitted before it.
    with ThreadPoolExecutor(max_workers=max(1, len(todo))) as pool:
        for unit in todo:
            futures[unit.id] = pool.submit(after_needs, unit)
        outcome = {uid: future.result() for uid, future in futures.items()}
    return outcome


def slurm_parameters(resources: Resources, name: str, stage: str) -> dict:
    """The submitit SlurmExecutor parameters of one stage's arrays (`_make_sbatch_string`'s names), from the stage's
    resources (`Resources.for_stage`: the masks and the table ask for no GPU). Jobs start in the folder the sweep was
    started from (`--chdir`), where the sweep file's relative paths and `resources.setup` hold."""
    resources = resources.for_stage(stage)
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


@dataclass
class Array:
    """One SLURM job array: units of one stage that share one dependency line. Task i runs `units[i]`."""

    name: str
    """`<stage>` when the stage is one array, else `<stage>_<k>` (its sbatch script and unit list in <sweep>/slurm/)."""
    stage: str
    units: list[Unit]
    kind: str | None = None
    """afterok, aftercorr (task i after task i of the one array it names) or afterany (the table); None: no
    dependency."""
    after: list[tuple[int, int | None]] = field(default_factory=list)
    """(index of an earlier array in the list, task or None for the whole array)."""

    def dependency(self, job_ids: list[str]) -> str | None:
        """The --dependency value, given each earlier array's SLURM job id (or a shell expression for it)."""
        if self.kind is None:
            return None
        return self.kind + ":" + ":".join(job_ids[a] + ("" if t is None else f"_{t}") for a, t in self.after)


def slurm_arrays(todo: list[Unit]) -> list[Array]:
    """The sweep's job arrays with per-task dependencies (a failed job blocks what reads its output, nothing else):

    - units with nothing to wait for: one array without a dependency;
    - a stage whose every unit reads exactly one task of one array, one to one (depth <- dense, test <- fit when the
      masks are done): one array in that array's order, `aftercorr` (task i after task i);
    - otherwise, one array per distinct set of tasks read, `afterok:<array>_<task>:...` (LLFF masks: per scene, after
      its depth task; a test: after its own fit and its own masks);
    - the table: `afterany` on every test (it shows what finished and a line per missing run).
    A dependency on every task of an array names the array (`afterok:<array>`)."""
    arrays: list[Array] = []
    where: dict[str, tuple[int, int]] = {}
    for stage in STAGES:
        units = [u for u in todo if u.stage == stage]
        if not units:
            continue
        needs = {u.id: sorted({where[n] for n in u.needs if n in where}) for u in units}
        groups: list[tuple[list[Unit], str | None, list]] = []
        free = [u for u in units if not needs[u.id]]
        bound = [u for u in units if needs[u.id]]
        if free:
            groups.append((free, None, []))
        corr = _corresponding(bound, needs, arrays) if stage != "table" else None
        if corr is not None:
            a, ordered = corr
            groups.append((ordered, "aftercorr", [(a, None)]))
        elif bound:
            kind = "afterany" if stage == "table" else "afterok"
            by_needs: dict[tuple, list[Unit]] = {}
            for u in bound:
                by_needs.setdefault(tuple(needs[u.id]), []).append(u)
            for key, group in by_needs.items():
                groups.append((group, kind, _compact(key, arrays)))
        for k, (group, kind, after) in enumerate(groups):
            name = stage if len(groups) == 1 else f"{stage}_{k}"
            arrays.append(Array(name, stage, group, kind, after))
            for task, u in enumerate(group):
                where[u.id] = (len(arrays) - 1, task)
    return arrays


def _corresponding(bound: list[Unit], needs: dict, arrays: list[Array]) -> tuple[int, list[Unit]] | None:
    """(array, units in its task order) when every unit reads one task of the same array and every task of that array
    is read by exactly one unit; else None."""
    if not bound or any(len(needs[u.id]) != 1 for u in bound):
        return None
    targets = {needs[u.id][0][0] for u in bound}
    if len(targets) != 1:
        return None
    a = targets.pop()
    tasks = sorted(needs[u.id][0][1] for u in bound)
    if tasks != list(range(len(arrays[a].units))):
        return None
    return a, sorted(bound, key=lambda u: needs[u.id][0][1])


def _compact(key: tuple, arrays: list[Array]) -> list[tuple[int, int | None]]:
    """Tasks read, with an array whose every task is read named whole."""
    tasks: dict[int, list[int]] = {}
    for a, t in key:
        tasks.setdefault(a, []).append(t)
    out: list[tuple[int, int | None]] = []
    for a, ts in tasks.items():
        out += [(a, None)] if sorted(ts) == list(range(len(arrays[a].units))) else [(a, t) for t in sorted(ts)]
    return out


def write_array_list(plan: Plan, arrays: list[Array], job_ids: list[str] | None = None) -> Path:
    """`<sweep>/slurm/arrays.json`: every array's name, stage, dependency and units in task order (what `sweep status`
    and `sweep cancel` map SLURM's job ids back to); `job_ids` once known (submit.sh appends them to submitted.txt)."""
    folder = plan.output / "slurm"
    folder.mkdir(parents=True, exist_ok=True)
    names = [a.name for a in arrays]
    data = [{"name": a.name, "stage": a.stage, "units": [u.id for u in a.units],
             "dependency": a.dependency(names)} for a in arrays]
    path = folder / ARRAYS
    path.write_text(json.dumps(data, indent=1))
    if job_ids is not None:
        (folder / SUBMITTED).write_text("".join(f"{a.name} {i}\n" for a, i in zip(arrays, job_ids, strict=True)))
    return path


def submit_slurm(plan: Plan, todo: list[Unit], log=print) -> dict[str, str]:
    """One submitit job array per `Array`, each with its per-task dependencies; returns array name -> SLURM job id."""
    import submitit

    arrays = slurm_arrays(todo)
    write_array_list(plan, arrays)
    ids: list[str] = []
    for array in arrays:
        ex = submitit.SlurmExecutor(folder=plan.output / "slurm" / "logs", max_num_timeout=0)
        params = slurm_parameters(plan.sweep.resources, plan.sweep.name, array.stage)
        dependency = array.dependency(ids)
        if dependency:
            params["additional_parameters"]["dependency"] = dependency
        ex.update_parameters(**params)
        jobs = ex.map_array(run_unit, [u.to_dict() for u in array.units])
        ids.append(str(jobs[0].job_id).split("_")[0])
        log(f"{array.name}: array {ids[-1]} of {len(array.units)} job(s)" + (f", {dependency}" if dependency else ""))
        write_array_list(plan, arrays[: len(ids)], ids)  # known so far: a failed submission leaves what went out
    write_array_list(plan, arrays, ids)
    return dict(zip([a.name for a in arrays], ids, strict=True))


def write_slurm_scripts(plan: Plan, todo: list[Unit]) -> list[Path]:
    """`--dry_run --executor slurm`: per array `<sweep>/slurm/<array>.sbatch` (what submitit would submit, its command
    `simplenerf sweep job` running unit $SLURM_ARRAY_TASK_ID of `<array>.json`), `arrays.json` and `submit.sh`,
    which submits them in order with their per-task dependencies and records the job ids in `submitted.txt` (for
    `sweep status` and `sweep cancel`). Nothing is submitted."""
    from submitit.slurm.slurm import _make_sbatch_string

    folder = plan.output / "slurm"
    folder.mkdir(parents=True, exist_ok=True)
    for old in [*folder.glob("*.sbatch"), folder / SUBMITTED]:  # an earlier dry run's arrays
        old.unlink(missing_ok=True)
    arrays = slurm_arrays(todo)
    write_array_list(plan, arrays)
    written = []
    lines = ["#!/bin/bash",
             f"# Submits the sweep {plan.sweep.name}: {len(arrays)} SLURM job arrays, each after the tasks whose "
             "output it reads (afterok:<array>_<task>, aftercorr: task i after task i; the table afterany).",
             "# Written by `python -m simplenerf sweep --dry_run --executor slurm`; submit with `bash submit.sh` (from "
             "any folder).", "set -euo pipefail", f"submitted={shlex.quote(str(folder / SUBMITTED))}",
             ': > "$submitted"  # array name and job id of each submission (`sweep status`, `sweep cancel`)']
    python = shlex.quote(sys.executable)
    shell_ids: list[str] = []
    for array in arrays:
        (folder / f"{array.name}.json").write_text(json.dumps([u.to_dict() for u in array.units], indent=1))
        command = (f"{python} -u -m simplenerf sweep job {shlex.quote(str(plan.output))} {array.name} "
                   "${SLURM_ARRAY_TASK_ID}")
        text = _make_sbatch_string(command=command, folder=folder / "logs", map_count=len(array.units),
                                   **slurm_parameters(plan.sweep.resources, plan.sweep.name, array.stage))
        path = folder / f"{array.name}.sbatch"
        path.write_text(text)
        written.append(path)
        dependency = array.dependency(shell_ids)
        var = array.name
        lines.append(f"{var}=$(sbatch --parsable{f' --dependency={dependency}' if dependency else ''} "
                     f"{shlex.quote(str(path))})")
        lines.append(f"{var}=${{{var}%%;*}}")
        lines.append(f'echo "{array.name} ${var}" >> "$submitted"')
        jobs = f"{len(array.units)} job{'s' if len(array.units) != 1 else ''}"
        lines.append(f'echo "{array.name}: job array ${var} ({jobs})'
                     + (f', {array.dependency([a.name for a in arrays])}' if dependency else "") + '"')
        shell_ids.append(f"${{{var}}}")
    script = folder / "submit.sh"
    script.write_text("\n".join(lines) + "\n")
    script.chmod(0o755)
    return [*written, script]
