"""Training callbacks: progress (a bar in a terminal, plain lines in a log file), throughput, checkpoints that
survive a crash, and a stop when the loss stops being a number."""

from __future__ import annotations

import datetime
import sys
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING

import lightning as L
import torch
from jsonargparse.typing import PositiveInt
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint, RichProgressBar

from simplenerf.errors import SimpleNeRFError, TrainingDiverged
from simplenerf.run.signals import Interrupted

if TYPE_CHECKING:
    from simplenerf.method.module import SimpleNeRF


class RaysPerSecond(L.Callback):
    """Shows training rays per second (smoothed) on the progress bar and logs it as `train/rays_per_s`."""

    def __init__(self, smoothing: float = 0.9) -> None:
        """
        Args:
            smoothing: weight of the past in the exponential moving average of the rate.
        """
        self.smoothing = smoothing
        self._start: float | None = None
        self._rate: float | None = None

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self._start = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if self._start is None:
            return
        rate = len(batch.rays) / max(time.perf_counter() - self._start, 1e-9)
        self._rate = rate if self._rate is None else self.smoothing * self._rate + (1 - self.smoothing) * rate
        pl_module.log("rays_per_s", self._rate, prog_bar=True, logger=False)
        pl_module.log("train/rays_per_s", rate)


class LearningRates(LearningRateMonitor):
    """Logs the learning rate every step; does nothing when the run has no logger (`--trainer.logger false`), where
    Lightning's own monitor refuses to start."""

    def __init__(self) -> None:
        super().__init__(logging_interval="step")

    def on_train_start(self, trainer, *args, **kwargs) -> None:
        if trainer.loggers:
            super().on_train_start(trainer, *args, **kwargs)

    def on_train_batch_start(self, trainer, *args, **kwargs) -> None:
        if trainer.loggers:
            super().on_train_batch_start(trainer, *args, **kwargs)


class Checkpointing(ModelCheckpoint):
    """Checkpoints every N steps plus `last.ckpt`, which is also written if training stops on an error, Ctrl-C or
    SIGTERM (then at the end of the step, `simplenerf.run.signals`).

    Resume with `--ckpt_path last`. The folder is `<trainer.default_root_dir>/checkpoints` (linked by the CLI).
    """

    def __init__(
        self, dirpath: str | None = None, every_n_train_steps: PositiveInt = 10000, save_top_k: int = -1
    ) -> None:
        """
        Args:
            dirpath: where checkpoints go.
            every_n_train_steps: save a numbered checkpoint every this many steps.
            save_top_k: numbered checkpoints to keep (-1: all).
        """
        super().__init__(
            dirpath=dirpath,
            filename="step{step:06d}",
            auto_insert_metric_name=False,
            every_n_train_steps=every_n_train_steps,
            save_top_k=save_top_k,
            save_last=True,
            enable_version_counter=False,  # a resumed run overwrites its own step files and last.ckpt
        )
        self._training = False  # whether training steps have started (a restore is complete)

    def on_train_end(self, trainer, pl_module) -> None:
        # max_steps need not be a multiple of every_n_train_steps: the final weights still end up in last.ckpt.
        if self.dirpath is not None and trainer.global_step > 0 and self._last_global_step_saved != trainer.global_step:
            trainer.save_checkpoint(f"{self.dirpath}/last.ckpt")

    def on_train_start(self, trainer, pl_module) -> None:
        super().on_train_start(trainer, pl_module)
        self._training = True

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        # After a divergence the weights are not worth keeping: last.ckpt stays the last good checkpoint. Nor are
        # they before training started (a restore may be half done), or after a second signal that stopped a step
        # half way (`signals.Interrupted`); a first SIGTERM or SIGINT stops between steps (Lightning's
        # SIGTERMException), where the state is whole and is saved.
        if isinstance(exception, (TrainingDiverged, Interrupted)) or not self._training:
            return
        if trainer.state.fn == "fit" and self.dirpath is not None and trainer.global_step > 0:
            trainer.save_checkpoint(f"{self.dirpath}/last.ckpt")


class StopOnNonFiniteLoss(L.Callback):
    """Stops training with `TrainingDiverged` as soon as the loss is NaN or infinite, before its backward pass and
    optimiser step, so the weights and every checkpoint written so far stay finite (`Checkpointing` then writes no
    last.ckpt). Costs one scalar device-to-host copy per step; under DDP the ranks decide together."""

    def on_before_backward(self, trainer, pl_module, loss: torch.Tensor) -> None:
        bad = not bool(torch.isfinite(loss.detach()).all())
        if trainer.world_size > 1:
            bad = trainer.strategy.reduce_boolean_decision(bad, all=False)
        if bad:
            raise TrainingDiverged(f"training stopped at step {trainer.global_step + 1}: the loss is "
                                   f"{loss.detach().float().item()}{non_finite_terms(pl_module)}")


def non_finite_terms(module) -> str:
    """" (non-finite: color, points)": the terms whose weighted value in the part being backpropagated is NaN or
    infinite (`SimpleNeRF.part_values`, `SimpleNeRF.terms`), or "" when none is or the module does not say."""
    values, terms = getattr(module, "part_values", None) or {}, getattr(module, "terms", None) or {}
    bad = [name for name, value in values.items()
           if name in terms and not bool(torch.isfinite(terms[name].weight * value).all())]
    return f" (non-finite: {', '.join(bad)})" if bad else ""


class TrainingProgressBar(RichProgressBar):
    """Rich's progress bar, with the training bar counting optimiser steps out of `max_steps`: after a resume it
    starts at the checkpoint's step, and its time estimate covers the steps still to run."""

    @property
    def total_train_batches(self) -> int | float:
        return self.trainer.max_steps if self.trainer.max_steps > 0 else super().total_train_batches

    def _get_train_description(self, current_epoch: int) -> str:
        return f"{'Training':{len(self.validation_description)}}"

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        super().on_train_epoch_start(trainer, pl_module)
        if self.progress is not None and self.train_progress_bar_id is not None:
            # Rich leaves the first progress sample out of its speed, so this jump does not distort the estimate.
            self.progress.update(self.train_progress_bar_id, completed=trainer.global_step)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        super().on_train_batch_end(trainer, pl_module, outputs, batch, trainer.global_step - 1)


def format_duration(seconds: float) -> str:
    """H:MM:SS, e.g. 0:03:20."""
    return str(datetime.timedelta(seconds=round(max(seconds, 0.0))))


class ProgressLog(L.Callback):
    """Plain progress lines for log files, printed when stdout is not a terminal (where the progress bar is not
    shown), e.g.

        step 120/500 (24%)  loss 0.0123  psnr 19.42  1534 rays/s  elapsed 0:01:02  eta 0:03:20
        step 250/500  validation  psnr 18.21
        step 250/500  checkpoint  runs/demo/checkpoints

    loss is the total training loss of the step, psnr the fine network's on the step's rays (`train/psnr_fine`),
    rays/s the smoothed throughput (`RaysPerSecond`) and eta the time the remaining steps take at this run's average
    pace so far. Printed by global rank 0.
    """

    def __init__(self, every_n_steps: PositiveInt | None = None, lines: bool | None = None) -> None:
        """
        Args:
            every_n_steps: print a training line every this many steps; null: about 100 lines per run
                (max_steps / 100).
            lines: print the lines; null: only when stdout is not a terminal (a log file or a pipe).
        """
        self.every_n_steps, self.lines = every_n_steps, lines
        self._active = False
        self._start_time = 0.0
        self._start_step = 0
        self._checkpoint_step: int | None = None

    def setup(self, trainer, pl_module, stage: str) -> None:
        self._active = trainer.is_global_zero and (self.lines if self.lines is not None else not sys.stdout.isatty())

    def _total(self, trainer) -> str:
        return str(trainer.max_steps) if trainer.max_steps > 0 else "?"

    def _print(self, trainer, text: str, percent: bool = False) -> None:
        step, total = trainer.global_step, trainer.max_steps
        where = f"step {step}/{self._total(trainer)}"
        if percent and total > 0:
            where += f" ({100 * step / total:.0f}%)"
        print(f"{where}  {text}", flush=True)

    def interval(self, trainer) -> int:
        if self.every_n_steps is not None:
            return max(1, self.every_n_steps)
        return max(1, trainer.max_steps // 100) if trainer.max_steps > 0 else 100

    def on_train_start(self, trainer, pl_module) -> None:
        self._start_time, self._start_step = time.perf_counter(), trainer.global_step
        if self._active and trainer.global_step > 0:
            self._print(trainer, f"resumed from {trainer.ckpt_path}")

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if not self._active or (step % self.interval(trainer) and step != trainer.max_steps):
            return
        metrics = trainer.callback_metrics
        parts = []
        for key, label, fmt in (("train/loss", "loss", ".4g"), ("train/psnr_fine", "psnr", ".2f")):
            if key in metrics:
                parts.append(f"{label} {float(metrics[key]):{fmt}}")
        if "rays_per_s" in metrics:
            parts.append(f"{float(metrics['rays_per_s']):.0f} rays/s")
        elapsed = time.perf_counter() - self._start_time
        parts.append(f"elapsed {format_duration(elapsed)}")
        done = step - self._start_step
        if trainer.max_steps > 0 and done > 0:
            parts.append(f"eta {format_duration(elapsed / done * (trainer.max_steps - step))}")
        self._print(trainer, "  ".join(parts), percent=True)

    def on_validation_end(self, trainer, pl_module) -> None:
        if not self._active or trainer.sanity_checking or trainer.state.fn != "fit":
            return
        scores = [f"{key.removeprefix('val/')} {float(value):.2f}" for key, value in trainer.callback_metrics.items()
                  if key.startswith("val/") and "/" not in key.removeprefix("val/")]
        self._print(trainer, "  ".join(["validation", *scores]))

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        # Called once per file (a numbered checkpoint and last.ckpt at the same step): one line per step.
        if not self._active or self._checkpoint_step == trainer.global_step:
            return
        self._checkpoint_step = trainer.global_step
        folder = trainer.checkpoint_callback.dirpath if trainer.checkpoint_callback is not None else None
        self._print(trainer, f"checkpoint  {folder}" if folder else "checkpoint")


class LossWeightSchedule(L.Callback):
    """Step-dependent loss weights as data: piecewise-constant schedules set before every training step.

    `schedules` maps the name of a term of the module's objective (`SimpleNeRF.terms`: color, sparse_depth, an
    augmentation's name, cfc, a field's regulariser such as tv_fine) to [[step, value], ...]: from each listed step
    on, the term's weight is its value (before the first listed step the configured weight stays). The paper's warm-up
    is {points: [[0, 0.0], [10000, 0.1]], views: ..., cfc: ...}. The module logs every term's weight as
    train_params/<name>.

    An augmentation whose own terms (`SimpleNeRF.own_terms`: its masked depth term and its mass concentration) are 0
    from a step to the end of the run is retired there (`SimpleNeRF.retired`): training stops rendering it, since
    nothing it renders reaches the main model again; e.g. `points: [[0, 0.0], [360, 0.1], [1600, 0.0]]` (with its
    concentration also 0 from 1600) saves its evaluations for the rest of the run. Its weights stay as trained at
    that step.
    """

    def __init__(self, schedules: dict[str, list[tuple[int, float]]]) -> None:
        """
        Args:
            schedules: loss name -> [[step, weight], ...] in increasing step order.
        """
        for name, points in schedules.items():
            steps = [step for step, _ in points]
            if steps != sorted(steps):
                raise ValueError(f"schedule of {name!r} must list steps in increasing order, got {steps}")
        self.schedules = schedules

    def value(self, name: str, step: int, default: float) -> float:
        """The weight of `name` at `step`: `default` before its first listed step, or throughout if not scheduled."""
        current = default
        for start, value in self.schedules.get(name, ()):
            if step >= start:
                current = value
        return current

    def zero_from(self, name: str, step: int, current: float) -> bool:
        """Whether the term `name`, of weight `current` at `step`, stays 0 to the end of the run."""
        return current == 0 and all(value == 0 for start, value in self.schedules.get(name, []) if start > step)

    def check_model(self, model: SimpleNeRF) -> None:
        """Every scheduled name must be one of the model's terms (`SimpleNeRF.terms`); the CLI calls this before any
        data is read, so a typo stops the run with one line instead of failing at the first batch."""
        unknown = sorted(set(self.schedules) - set(model.terms))
        if unknown:
            raise SimpleNeRFError(
                f"LossWeightSchedule schedules {', '.join(map(repr, unknown))}, but the model's losses are "
                f"{', '.join(sorted(model.terms))} (augmentation names come from model.augmentations)"
            )

    def retired(self, model: SimpleNeRF, step: int) -> frozenset[str]:
        """The augmentations retired at `step`: all their own terms 0 from there to the end of the run (a term not
        scheduled keeps its weight in `model`). Retired at step 0: never rendered in training, so never trained."""
        return frozenset(
            aug.name for aug in model.augmentations
            if all(self.zero_from(name, step, self.value(name, step, model.terms[name].weight))
                   for name in model.own_terms(aug.name))
        )

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.check_model(pl_module)
        step = trainer.global_step
        for name in self.schedules:
            term = pl_module.terms[name]
            term.weight = self.value(name, step, term.weight)
        pl_module.retired = self.retired(pl_module, step)


def untrained_augmentations(model: SimpleNeRF, callbacks: Iterable[L.Callback]) -> frozenset[str]:
    """The augmentations that the run's `LossWeightSchedule` (among `callbacks`) retires from step 0: never rendered
    in training, so their fields are as initialised (e.g. an ablation without L_ap and L_av); empty without one."""
    schedule = next((c for c in callbacks if isinstance(c, LossWeightSchedule)), None)
    return schedule.retired(model, 0) if schedule is not None else frozenset()
