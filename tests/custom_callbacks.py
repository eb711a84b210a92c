"""A callback that breaks training on purpose (named by class_path in a test's YAML), for the NaN-loss test."""

from __future__ import annotations

import lightning as L


class PoisonLossAt(L.Callback):
    """Makes the colour loss weight NaN from the training step that starts at global step `step` on: the total loss
    is then NaN while everything else stays finite."""

    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            pl_module.loss_weights["color"] = float("nan")
