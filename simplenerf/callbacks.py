"""Training callbacks: throughput on the progress bar, and checkpoints that survive a crash."""

from __future__ import annotations

import time

import lightning as L
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint


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
        rate = batch["rgb"].shape[0] / max(time.perf_counter() - self._start, 1e-9)
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
    """Checkpoints every N steps plus `last.ckpt`, which is also written if training stops on an error or Ctrl-C.

    Resume with `--ckpt_path last`. The folder is `<trainer.default_root_dir>/checkpoints` (linked by the CLI).
    """

    def __init__(self, dirpath: str | None = None, every_n_train_steps: int = 10000, save_top_k: int = -1) -> None:
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
        )

    def on_train_end(self, trainer, pl_module) -> None:
        # max_steps need not be a multiple of every_n_train_steps: the final weights still end up in last.ckpt.
        if self.dirpath is not None and trainer.global_step > 0 and self._last_global_step_saved != trainer.global_step:
            trainer.save_checkpoint(f"{self.dirpath}/last.ckpt")

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        if trainer.state.fn == "fit" and self.dirpath is not None and trainer.global_step > 0:
            trainer.save_checkpoint(f"{self.dirpath}/last.ckpt")


class LossWeightSchedule(L.Callback):
    """Step-dependent loss weights as data: piecewise-constant schedules set before every training step.

    `schedules` maps a loss name of the module's `loss_weights` to [[step, value], ...]: from each listed step on,
    the weight is its value (before the first listed step the module's own weight stays). The paper's warm-up is
    {points: [[0, 0.0], [10000, 0.1]], views: ..., cfc: ...}. Each scheduled weight is logged as train_params/<name>.
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
        """The weight of `name` at `step`."""
        current = default
        for start, value in self.schedules[name]:
            if step >= start:
                current = value
        return current

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        for name in self.schedules:
            if name not in pl_module.loss_weights:
                raise KeyError(f"scheduled loss {name!r} is not one of {sorted(pl_module.loss_weights)}")
            pl_module.loss_weights[name] = self.value(name, trainer.global_step, pl_module.loss_weights[name])
            pl_module.log(f"train_params/{name}", pl_module.loss_weights[name])
