"""What one job of a sweep does (`run_unit`), in the process the executor gives it: submitit's job process on SLURM
or on this machine, or the sweep's own process (debug).

The stages run the package's own entry points in-process (`simplenerf.run.cli.make_cli` for fit / test, the verbs'
functions for depth export and masks), so on SLURM the fit is the job's process itself and receives SLURM's signal:
Lightning's `SLURMEnvironment(auto_requeue=True)` saves `hpc_ckpt_N.ckpt` on SIGUSR1 (sbatch `--signal=USR1@90`)
and requeues the job with `scontrol requeue`; the requeued job runs this again, in the same run folder and with the
same W&B run id, and resumes from the newest of `hpc_ckpt_N.ckpt` and `last.ckpt`. submitit does not requeue: the
job function has no `checkpoint()` and SLURM never sends submitit's own signal (USR2).

A fit is done only if it reached its max_steps: a run cut short (a signal, Ctrl-C, an error) returns or raises before
that and its state says failed or stopped, so the next sweep resumes it. A failed job raises `JobFailed` (a non-zero
exit status of the job: SLURM's afterok dependencies then do not start what needs it).
"""

from __future__ import annotations

import contextlib
import io
import os
import socket
import sys
import time
from pathlib import Path

import torch

from simplenerf.errors import SimpleNeRFError
from simplenerf.experiments.plan import Unit
from simplenerf.experiments.state import checkpoint_steps, job_id, now, read_state, wall_time, write_state


class JobFailed(RuntimeError):
    """A sweep job did not finish; the message is its one-line reason."""


class _LastLine(io.TextIOBase):
    """A stderr that passes everything on and remembers the last `error:` line (the CLI's one-line errors)."""

    def __init__(self, stream) -> None:
        self.stream, self.line = stream, None

    def write(self, text: str) -> int:
        for line in text.splitlines():
            if "error:" in line:
                self.line = line.strip()
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


def resume_checkpoint(folder: Path) -> str:
    """`hpc` when Lightning's requeue checkpoint (`<run>/hpc_ckpt_N.ckpt`) is newer than `checkpoints/last.ckpt`, else
    `last` (from the start when there is none: `simplenerf.run.checks.resolve_checkpoint`)."""
    hpc = sorted(Path(folder).glob("hpc_ckpt_*.ckpt"), key=lambda p: p.stat().st_mtime)
    last = Path(folder) / "checkpoints" / "last.ckpt"
    if hpc and (not last.is_file() or hpc[-1].stat().st_mtime > last.stat().st_mtime):
        return "hpc"
    return "last"


def run_cli(args: list[str]):
    """The CLI on `args` in this process; JobFailed with its one error line if it stops on an error."""
    from simplenerf.run.cli import make_cli
    from simplenerf.run.console import quiet_libraries

    quiet_libraries()
    tee = _LastLine(sys.stderr)
    try:
        with contextlib.redirect_stderr(tee):
            return make_cli(args)
    except SystemExit as e:
        if e.code in (0, None):
            return None
        raise JobFailed(tee.line or f"exit status {e.code}") from None
    except SimpleNeRFError as e:
        raise JobFailed(f"{type(e).__name__}: {e}") from None
    finally:
        _finish_wandb()


def _finish_wandb() -> None:
    """Closes this process's W&B run, so that the next job in the same process (debug executor) starts its own."""
    wandb = sys.modules.get("wandb")
    if wandb is not None and getattr(wandb, "run", None) is not None:
        with contextlib.suppress(Exception):
            wandb.finish()


def _fit(unit: Unit) -> int:
    folder = Path(unit.folder)
    cli = run_cli(["fit", *unit.args, *unit.logger_args, "--ckpt_path", resume_checkpoint(folder)])
    step = cli.trainer.global_step if cli is not None else checkpoint_steps(folder) or 0
    max_steps = cli.trainer.max_steps if cli is not None else unit.extra.get("max_steps")
    if cli is None or cli.trainer.interrupted or (max_steps is not None and max_steps > 0 and step < max_steps):
        raise JobFailed(f"stopped at step {step} of {max_steps} (resumes from {folder / 'checkpoints'})")
    return step


def _test(unit: Unit) -> None:
    summary = Path(unit.folder) / "test" / "summary.json"
    before = summary.stat().st_mtime if summary.is_file() else None
    run_cli(["test", *unit.args, *unit.logger_args, "--ckpt_path", "last"])
    if not summary.is_file() or summary.stat().st_mtime == before:
        raise JobFailed(f"test wrote no {summary}")
    if unit.extra.get("heldout_depth"):
        _heldout_depth(unit)


def _heldout_depth(unit: Unit) -> None:
    """The test's depth error at held-out SfM points (the sweep's `heldout_depth`), written as `simplenerf
    heldout-depth --out` writes it, to `<run>/heldout_depth.json`, where the results table reads it."""
    import json

    from simplenerf.evaluation.heldout_depth import heldout_depth_error, heldout_observations
    from simplenerf.run.callbacks import untrained_augmentations
    from simplenerf.run.cli import load_for_tool

    ckpt = Path(unit.folder) / "checkpoints" / "last.ckpt"
    try:
        cli = load_for_tool([], unit.args, ckpt=str(ckpt), device=_device())
        dm, model = cli.datamodule, cli.model
        observations = heldout_observations(dm.scene, unit.extra["heldout_cache"])
        untrained = untrained_augmentations(model, cli.trainer.callbacks)
        result = heldout_depth_error(model, dm.scene, observations, dm.near, model.hparams.chunk, untrained=untrained)
    except SimpleNeRFError as e:
        raise JobFailed(f"held-out depth: {type(e).__name__}: {e}") from None
    Path(unit.extra["heldout_depth"]).write_text(json.dumps({"ckpt": str(ckpt), **result}) + "\n")
    print(f"held-out SfM depth error {result['rel_error_mean']:.4f} (mean): {unit.extra['heldout_depth']}", flush=True)


def _device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def _depth(unit: Unit) -> None:
    from simplenerf.evaluation.reference_depth import export_reference_depth
    from simplenerf.run.cli import load_for_tool

    ckpt = Path(unit.folder) / "checkpoints" / "last.ckpt"
    try:
        cli = load_for_tool([], unit.args, ckpt=str(ckpt), device=_device())
        dm, model = cli.datamodule, cli.model
        # A depth job cut short keeps its frames: the folder belongs to this dense NeRF (the same digest).
        paths = export_reference_depth(model.nerf, dm.scene, dm.near, model.hparams.chunk, unit.extra["out"],
                                       skip_existing=True)
    except SimpleNeRFError as e:
        raise JobFailed(f"{type(e).__name__}: {e}") from None
    print(f"wrote {len(paths)} depth maps to {unit.extra['out']}", flush=True)


def _masks(unit: Unit) -> None:
    from simplenerf.evaluation.evaluator import export_visibility_masks
    from simplenerf.run.cli import load_for_tool

    try:
        cli = load_for_tool([], unit.args)
        fractions = export_visibility_masks(cli.datamodule.scene, unit.extra["out"])
    except SimpleNeRFError as e:
        raise JobFailed(f"{type(e).__name__}: {e}") from None
    print(f"visibility masks of {len(fractions)} test frames in {unit.extra['out']}", flush=True)


def _table(unit: Unit) -> None:
    from simplenerf.experiments.results import write_results

    written = write_results(Path(unit.folder), unit.extra["runs"], unit.extra["tables"],
                            unit.extra.get("scores", "masked"))
    print(f"results: {', '.join(map(str, written))}", flush=True)


STAGE_FUNCTIONS = {"dense": _fit, "depth": _depth, "masks": _masks, "fit": _fit, "test": _test, "table": _table}


def run_unit(unit: Unit | dict, raise_on_failure: bool = True) -> str:
    """Runs one unit, keeping its state file up to date; returns "done" or "failed" (JobFailed is raised instead when
    `raise_on_failure`, so that the job's exit status says it: submitit and SLURM see a failed job)."""
    unit = Unit.from_dict(unit) if isinstance(unit, dict) else unit
    folder = Path(unit.folder)
    if unit.extra.get("wandb_mode"):  # the sweep file's wandb.mode (W&B reads it when the run starts)
        os.environ["WANDB_MODE"] = unit.extra["wandb_mode"]
    previous = read_state(folder, unit.stage) or {}
    same = previous.get("digest") == unit.digest
    # An attempt killed without a word (its state still says running) counts until its newest file.
    wall = wall_time("stopped" if previous.get("status") == "running" else "done", previous, folder) if same else 0.0
    state = {"stage": unit.stage, "key": unit.key, "digest": unit.digest, "status": "running", "started": now(),
             "ended": None, "wall_s": round(wall, 1),
             "attempts": (previous.get("attempts", 0) if same else 0) + 1, "host": socket.gethostname(),
             "pid": os.getpid(), "job_id": job_id(), "error": None, "steps": checkpoint_steps(folder),
             "max_steps": unit.extra.get("max_steps")}
    if unit.stage == "test":
        fit = read_state(folder, "fit") or {}
        state["fit_ended"] = fit.get("ended")
    write_state(folder, unit.stage, state)
    start = time.monotonic()
    threads = torch.get_num_threads()
    torch.set_num_threads(unit.extra.get("cpus") or threads)  # resources.cpus_per_job (the debug executor: restored)
    print(f"sweep job {unit.id} ({folder}), attempt {state['attempts']}, {torch.get_num_threads()} CPU thread(s)",
          flush=True)
    try:
        STAGE_FUNCTIONS[unit.stage](unit)
        state.update(status="done")
    except JobFailed as e:
        state.update(status="failed", error=str(e))
    except BaseException as e:  # a bug or an interrupt: recorded, then passed on
        text = str(e).strip()
        state.update(status="failed", error=f"{type(e).__name__}: {text.splitlines()[0] if text else ''}")
        _close(state, folder, unit, start)
        raise
    finally:
        torch.set_num_threads(threads)
    _close(state, folder, unit, start)
    if state["status"] == "failed":
        print(f"sweep job {unit.id} failed: {state['error']}", file=sys.stderr, flush=True)
        if raise_on_failure:
            raise JobFailed(f"{unit.id}: {state['error']}")
    return state["status"]


def _close(state: dict, folder: Path, unit: Unit, start: float) -> None:
    state.update(ended=now(), wall_s=round(state["wall_s"] + time.monotonic() - start, 1),
                 steps=checkpoint_steps(folder))
    write_state(folder, unit.stage, state)


def main(argv: list[str]) -> None:
    """`python -m simplenerf sweep job SWEEP_DIR STAGE INDEX`: unit INDEX of `<SWEEP_DIR>/slurm/<STAGE>.json` (the
    self-contained sbatch scripts of `sweep --dry_run --executor slurm`)."""
    import json

    if len(argv) != 3:
        raise SimpleNeRFError("usage: simplenerf sweep job SWEEP_DIR STAGE INDEX")
    folder, stage, index = Path(argv[0]), argv[1], int(argv[2])
    units = json.loads((folder / "slurm" / f"{stage}.json").read_text())
    run_unit(Unit.from_dict(units[index]))
