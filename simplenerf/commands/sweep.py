"""Scenes x views x models x seeds as jobs: dense reference NeRF -> reference depth -> visibility masks; fit -> test
-> results table (markdown + CSV in the sweep folder). Rerunning skips what finished, resumes what was cut and reruns
what failed (simplenerf.experiments, docs/experiments.md), e.g.

    simplenerf sweep --config configs/sweeps/cpu_grid.yaml --executor local
    simplenerf sweep --config configs/sweeps/llff_table1.yaml --executor slurm --dry_run
    simplenerf sweep status SWEEP_DIR                 (every job's state; SLURM's too when squeue / sacct are here)
    simplenerf sweep cancel SWEEP_DIR                 (scancel what of its SLURM submission is queued or running)
    simplenerf sweep job SWEEP_DIR STAGE INDEX        (what the sbatch scripts of --dry_run run)
"""

from __future__ import annotations

import time
from pathlib import Path

from simplenerf.commands import CommandParser
from simplenerf.experiments.executors import run_here, submit_slurm, units_to_run, write_manifest, write_slurm_scripts
from simplenerf.experiments.plan import build_plan, link_reused
from simplenerf.experiments.preflight import PreflightError, preflight
from simplenerf.experiments.spec import EXECUTORS, STAGES, SweepError, load_sweep
from simplenerf.experiments.state import process_alive, read_state, read_status
from simplenerf.experiments.status import status_table


def build_parser() -> CommandParser:
    p = CommandParser("sweep", __doc__)
    p.add_argument("--config", required=True, help="the sweep file (e.g. configs/sweeps/cpu_grid.yaml)")
    p.add_argument("--executor", choices=EXECUTORS, help="slurm, local or debug (default: the sweep file's)")
    p.add_argument("--dry_run", action="store_true",
                   help="check everything and show what would run; slurm: write the sbatch scripts and submit.sh "
                        "into <sweep>/slurm/ instead of submitting")
    return p


def main(argv: list[str]) -> None:
    if argv[:1] == ["status"]:
        if len(argv) != 2:
            raise SystemExit("usage: simplenerf sweep status SWEEP_DIR")
        print(status_table(Path(argv[1])))
        return
    if argv[:1] == ["cancel"]:
        from simplenerf.experiments.slurm import cancel

        if len(argv) != 2:
            raise SystemExit("usage: simplenerf sweep cancel SWEEP_DIR")
        cancel(Path(argv[1]))
        return
    if argv[:1] == ["job"]:
        from simplenerf.experiments.jobs import main as job

        job(argv[1:])
        return
    args = build_parser().parse_args(argv)
    sweep = load_sweep(args.config)
    executor = args.executor or sweep.executor
    start = time.monotonic()
    plan = build_plan(sweep, args.config, check_scenes=not args.dry_run)
    link_reused(plan)
    for warning in plan.warnings:
        print(f"warning: {warning}")
    todo = units_to_run(plan)
    counts = ", ".join(f"{sum(u.stage == s for u in todo)}/{len(plan.stage(s))} {s}" for s in STAGES
                       if plan.stage(s))
    print(f"sweep {sweep.name}: {len(plan.units)} jobs in {plan.output}; to run: {counts}")
    problems = preflight(plan, executor)
    if args.dry_run:
        for problem in problems:
            print(f"warning: a submission would stop here: {problem}")
        for unit in todo:
            print(f"  {unit.stage} {unit.key}" + (f"  (after {', '.join(unit.needs)})" if unit.needs and
                                                  unit.stage != "table" else ""))
        if executor == "slurm":
            write_manifest(plan)  # for `sweep status` once the scripts are submitted
            written = write_slurm_scripts(plan, todo)
            print(f"wrote {', '.join(str(p) for p in written)}; submit with: bash {written[-1]}")
        return
    live = [u for u in todo if read_status(Path(u.folder), u.stage, u.digest)[0] == "running"
            and process_alive(read_state(Path(u.folder), u.stage) or {})]
    if live:
        state = read_state(Path(live[0].folder), live[0].stage) or {}
        raise SweepError(f"{live[0].stage} {live[0].key} is running (process {state.get('pid')} on this machine): "
                         "one sweep at a time in a sweep folder; wait for it, or stop it and run the sweep again")
    if problems:
        raise PreflightError(f"{len(problems)} problem(s) found before anything ran; nothing was submitted:\n"
                             + "\n".join(f"  {p}" for p in problems))
    write_manifest(plan)
    if executor == "slurm":
        submit_slurm(plan, todo)
        print(f"submitted; follow with: python -m simplenerf sweep status {plan.output}")
        return
    try:
        outcome = run_here(plan, todo, executor)
    except KeyboardInterrupt:  # Ctrl-C reaches the jobs too: Lightning saves last.ckpt and they stop
        print(f"sweep {sweep.name}: interrupted; the same command resumes it "
              f"(python -m simplenerf sweep status {plan.output} lists every job)", flush=True)
        raise SystemExit(130) from None
    failed = [k for k, v in outcome.items() if v != "done"]
    print(status_table(plan.output))
    print(f"sweep {sweep.name}: {len(outcome) - len(failed)} of {len(outcome)} jobs done in "
          f"{time.monotonic() - start:.0f} s; results: {plan.output / 'results.md'}")
    if failed:
        raise SystemExit(1)
