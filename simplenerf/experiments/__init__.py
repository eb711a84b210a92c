"""The paper's experiments as one command: scenes x views x models x seeds, with their dense references, tests and
results table, on a SLURM cluster or on this machine (`python -m simplenerf sweep`).

    spec.py       the sweep file (dataclasses jsonargparse checks)
    plan.py       the sweep as units (jobs) of the stages dense -> depth -> masks, fit -> test -> table, with digests
    state.py      a job's state file in its folder (running / done / failed, steps, wall time)
    jobs.py       what a job does (`run_unit`), in the process its executor gives it
    executors.py  submitit: SLURM job arrays with per-task dependencies, local processes (a GPU each), or in-process
    preflight.py  what is checked before anything is submitted (scenes, LPIPS weights, W&B mode, output)
    slurm.py      what squeue / sacct say of a submitted sweep; `sweep cancel`
    results.py    the results table beside the paper's rows (simplenerf.reporting.tables), a line per missing run
    status.py     `sweep status SWEEP_DIR`
    (the command line: simplenerf/commands/sweep.py)
"""
