"""Training callbacks: throughput on the progress bar, and checkpoints that survive a crash."""

from __future__ import annotations

import time

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint


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

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        if trainer.state.fn == "fit" and self.dirpath is not None and trainer.global_step > 0:
            trainer.save_checkpoint(f"{self.dirpath}/last.ckpt")
