"""Refactors and speed work must not change what a training step computes: the losses of the first training steps
of the demo config (SimpleNeRF with every term on from step 0, fp32, seed 0) are pinned to values recorded before.

Recorded with `python tests/test_pinned_losses.py` (prints the values) at commit 4d91795, before the field contract,
typed batches and the data-module base were introduced.
"""

from __future__ import annotations

import sys
from pathlib import Path

import lightning as L
import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
STEPS = 20
TERMS = ("loss", "loss_color", "loss_sparse_depth", "loss_points", "loss_views", "loss_cfc")

# Every masked loss on from step 0 (the demo's warm-up would leave them at weight 0 for these steps).
NO_WARMUP = """
trainer:
  callbacks:
    - class_path: simplenerf.callbacks.LossWeightSchedule
      init_args:
        schedules:
          points: [[0, 0.1]]
          views: [[0, 0.1]]
          cfc: [[0, 0.1]]
"""


class RecordLosses(L.Callback):
    def __init__(self) -> None:
        self.rows: list[dict[str, float]] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        metrics = trainer.callback_metrics
        self.rows.append({t: float(metrics[f"train/{t}"]) for t in TERMS})


def demo_losses(workdir: Path, steps: int = STEPS) -> list[dict[str, float]]:
    """Per-step losses of `steps` fp32 steps of configs/demo.yaml with seed 0, data and outputs under `workdir`."""
    from simplenerf.cli import make_cli
    from simplenerf.data import sparse_depth

    # COLMAP's multi-threaded SfM differs from run to run in the last bits; one thread is reproducible.
    compute = sparse_depth.compute_sparse_depth
    sparse_depth.compute_sparse_depth = lambda *a, **k: compute(*a, **{**k, "num_threads": 1})

    override = workdir / "no_warmup.yaml"
    override.write_text(NO_WARMUP)
    args = [
        "--config", str(REPO / "configs/demo.yaml"), "--config", str(override),
        "--seed_everything", "0", "--trainer.max_steps", str(steps), "--trainer.logger", "false",
        "--trainer.precision", "32-true", "--model.coarse_fine_on_sparse_rays", "false",
        "--trainer.val_check_interval", "1000",
        "--trainer.default_root_dir", str(workdir / "run"),
        "--data.init_args.root", str(workdir / "synthetic"),
        "--data.init_args.sparse_depth_cache", str(workdir / "cache"),
    ]  # fmt: skip
    torch.set_num_threads(torch.get_num_threads())
    cli = make_cli(args, run=False)
    recorder = RecordLosses()
    cli.trainer.callbacks.append(recorder)
    try:
        cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    finally:
        sparse_depth.compute_sparse_depth = compute
    return recorder.rows


# Recorded at commit 4d91795 (see the module docstring): steps 0, 1, 2, 9 and 19.
PINNED = {
    0: {
        "loss": 2.2727863788604736,
        "loss_color": 0.7173808813095093,
        "loss_sparse_depth": 12.7344970703125,
        "loss_points": 0.9897811412811279,
        "loss_views": 1.0989857912063599,
        "loss_cfc": 0.730792224407196,
    },
    1: {
        "loss": 1.8618834018707275,
        "loss_color": 0.5735512971878052,
        "loss_sparse_depth": 10.055931091308594,
        "loss_points": 1.1296828985214233,
        "loss_views": 0.9861195087432861,
        "loss_cfc": 0.7115864157676697,
    },
    2: {
        "loss": 1.2090028524398804,
        "loss_color": 0.4494816064834595,
        "loss_sparse_depth": 6.365450859069824,
        "loss_points": 0.3685334622859955,
        "loss_views": 0.37071433663368225,
        "loss_cfc": 0.4905144274234772,
    },
    9: {
        "loss": 0.815284788608551,
        "loss_color": 0.3476652503013611,
        "loss_sparse_depth": 3.5257344245910645,
        "loss_points": 0.27060744166374207,
        "loss_views": 0.46729233860969543,
        "loss_cfc": 0.4125612676143646,
    },
    19: {
        "loss": 0.6070441603660583,
        "loss_color": 0.34883373975753784,
        "loss_sparse_depth": 1.6906543970108032,
        "loss_points": 0.19810724258422852,
        "loss_views": 0.3242199122905731,
        "loss_cfc": 0.36912235617637634,
    },
}


def test_demo_losses_are_unchanged(tmp_path):
    rows = demo_losses(tmp_path)
    for step, expected in PINNED.items():
        for term, value in expected.items():
            assert rows[step][term] == pytest.approx(value, rel=1e-6), (step, term)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        rows = demo_losses(Path(tmp), int(sys.argv[1]) if len(sys.argv) > 1 else STEPS)
    for step in (0, 1, 2, 9, 19):
        print(f"    {step}: {{" + ", ".join(f'"{t}": {rows[step][t]!r}' for t in TERMS) + "},")
