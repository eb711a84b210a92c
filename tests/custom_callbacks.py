"""Callbacks the tests name by class_path in their YAML: one breaks training on purpose (the NaN-loss test), one
logs every step's loss (the resume test)."""

from __future__ import annotations

import lightning as L


class PoisonLossAt(L.Callback):
    """Makes the colour loss weight NaN from the training step that starts at global step `step` on: the total loss
    is then NaN while everything else stays finite."""

    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            pl_module.terms["color"].weight = float("nan")


class LossLog(L.Callback):
    """Appends `step loss` (the step's total training loss, full precision) to the file `path` after every training
    step, for comparing a resumed run's losses with a straight run's."""

    def __init__(self, path: str) -> None:
        self.path = path

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        with open(self.path, "a") as f:
            f.write(f"{trainer.global_step} {float(trainer.callback_metrics['train/loss']).hex()}\n")


class SlowTest(L.Callback):
    """Prints `frame N done` after each test frame and then waits `seconds`, so a test can signal a `test` run
    between its frames."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds

    def on_test_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        import time

        print(f"frame {batch_idx} done", flush=True)
        time.sleep(self.seconds)


class StepRecord(L.Callback):
    """Appends `rank step checksum terms` after every training step to the file `path`: the sum of the model's
    parameters (exact, as hex) and the logged loss terms, so that ranks can be compared after DDP steps."""

    def __init__(self, path: str) -> None:
        self.path = path

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:

        total = sum(p.detach().double().sum() for p in pl_module.parameters())
        terms = ",".join(sorted(k for k in trainer.callback_metrics if k.startswith("train/loss_")))
        with open(self.path, "a") as f:
            f.write(f"{trainer.global_rank} {trainer.global_step} {float(total).hex()} {terms}\n")
