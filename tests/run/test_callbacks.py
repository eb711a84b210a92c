"""Training callbacks in isolation: the progress bar's step count, the progress-line interval, the NaN stop."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from lightning.pytorch.callbacks import RichProgressBar

from simplenerf.errors import TrainingDiverged
from simplenerf.run.callbacks.training import ProgressLog, StopOnNonFiniteLoss, TrainingProgressBar, format_duration


def test_progress_bar_counts_optimiser_steps_after_a_resume(monkeypatch):
    bar = TrainingProgressBar()
    trainer = SimpleNamespace(max_steps=6, global_step=5)
    bar._trainer = trainer
    assert bar.total_train_batches == 6  # the run's steps, not the batches left in this process
    shown = []
    monkeypatch.setattr(RichProgressBar, "on_train_batch_end", lambda self, t, m, o, b, i: shown.append(i + 1))
    bar.on_train_batch_end(trainer, None, None, None, batch_idx=0)  # the first batch after resuming at step 4
    assert shown == [5]


def test_progress_line_interval_and_durations():
    trainer = SimpleNamespace(max_steps=100000)
    assert ProgressLog().interval(trainer) == 1000  # about 100 lines per run
    assert ProgressLog(every_n_steps=50).interval(trainer) == 50
    assert ProgressLog().interval(SimpleNamespace(max_steps=20)) == 1
    assert format_duration(200.4) == "0:03:20" and format_duration(90061) == "1 day, 1:01:01"


def test_a_non_finite_loss_stops_before_its_backward_pass():
    guard = StopOnNonFiniteLoss()
    trainer = SimpleNamespace(world_size=1, global_step=3)
    guard.on_before_backward(trainer, None, torch.tensor(0.5))
    for value in (float("nan"), float("inf")):
        with pytest.raises(TrainingDiverged, match=f"^training stopped at step 4: the loss is {value}$"):
            guard.on_before_backward(trainer, None, torch.tensor(value))
    assert TrainingDiverged.exit_status == 1
    # the module's terms of the part being backpropagated: the line names those whose weighted value is not finite
    module = SimpleNamespace(part_values={"color": torch.tensor(0.1), "points": torch.tensor(float("nan")),
                                          "views": torch.tensor(float("inf")), "cfc": torch.tensor(0.2)},
                             terms={name: SimpleNamespace(weight=w) for name, w in
                                    (("color", 1.0), ("points", 0.1), ("views", 1.0), ("cfc", float("nan")))})
    with pytest.raises(TrainingDiverged, match=r"^training stopped at step 4: the loss is nan \(non-finite: points, "
                                               r"views, cfc\)$"):
        guard.on_before_backward(trainer, module, torch.tensor(float("nan")))
