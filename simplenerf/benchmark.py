"""Training-speed measurement: seconds per iteration and peak memory of a configured model on this machine."""

from __future__ import annotations

import resource
import statistics
import time

import lightning as L
import torch


class StepTimer(L.Callback):
    """Wall time of every training step (forward, backward, optimiser), measured around the whole batch."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self._start = 0.0

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        self._start = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        self.times.append(time.perf_counter() - self._start)


def time_training(
    model: L.LightningModule, datamodule: L.LightningDataModule, steps: int, warmup: int, precision: str
) -> dict[str, float]:
    """Trains for warmup + steps iterations and reports the steady-state time per iteration.

    Returns:
        s_per_it (median over the timed steps), s_per_it_min, peak_rss_gib (the process's peak resident memory,
        which includes the data), peak_cuda_gib (0 without CUDA).
    """
    timer = StepTimer()
    trainer = L.Trainer(
        max_steps=warmup + steps,
        precision=precision,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        callbacks=[timer],
    )
    trainer.fit(model, datamodule)
    timed = timer.times[warmup:]
    peak_cuda = torch.cuda.max_memory_allocated() / 2**30 if torch.cuda.is_available() else 0.0
    return {
        "s_per_it": statistics.median(timed),
        "s_per_it_min": min(timed),
        "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
        "peak_cuda_gib": peak_cuda,
    }
