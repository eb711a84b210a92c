"""Tiny sweeps on generated synthetic scenes (exact depth, 48x64): a model config in LLFF layout at a few seconds per
fit, its DS-NeRF variant, a tiny dense reference NeRF, and a sweep file over them."""

from __future__ import annotations

from pathlib import Path

import yaml
from lightning.pytorch import Callback

from simplenerf.synthetic.generate import make_synthetic_scene
from tests.conftest import REPO
from tests.run.test_cli import shrink

STEPS = 4


def tiny_configs(tmp: Path, steps: int = STEPS) -> dict[str, Path]:
    """simplenerf.yaml (the demo's SimpleNeRF shrunk, LLFF data at factor 1), dsnerf.yaml (an override: no
    augmentations, no L_cfc, no warm-up) and dense.yaml (every non-test frame, colour loss only)."""
    tmp.mkdir(parents=True, exist_ok=True)
    demo = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    model = {**demo["model"], "nerf": shrink(demo["model"]["nerf"]),
             "augmentations": shrink(demo["model"]["augmentations"]), "chunk": 4096}
    data = {"class_path": "simplenerf.data.LLFFDataModule",
            "init_args": {"scene_dir": "unset", "factor": 1, "n_views": 2, "rays_per_batch": 64,
                          "sparse_rays_per_batch": 0}}
    trainer = {"max_steps": steps, "val_check_interval": 1000, "callbacks": [{
        "class_path": "simplenerf.run.callbacks.LossWeightSchedule",
        "init_args": {"schedules": {k: [[0, 0.0], [1, 0.1]] for k in ("points", "views", "cfc")}}}],
        "logger": {"class_path": "simplenerf.run.loggers.WandbLogger", "init_args": {"save_dir": "unset"}}}
    simplenerf = {"model": model, "data": data, "trainer": trainer, "checkpoint": {"every_n_train_steps": 2},
                  "evaluation": {"lpips": False}}
    dsnerf = {"model": {"augmentations": [], "objective": {"coarse_fine_mask": None}}, "trainer": {"callbacks": []}}
    dense = {**simplenerf, "model": {**model, "augmentations": [], "objective": {"coarse_fine_mask": None}},
             "data": {**data, "init_args": {**data["init_args"], "n_views": None}},
             "trainer": {**trainer, "callbacks": []}}
    paths = {}
    for name, config in (("simplenerf", simplenerf), ("dsnerf", dsnerf), ("dense", dense)):
        paths[name] = tmp / f"{name}.yaml"
        paths[name].write_text(yaml.safe_dump(config, sort_keys=False))
    return paths


def synthetic_scenes(tmp: Path, n: int = 2) -> list[Path]:
    return [make_synthetic_scene(tmp / f"scene{i}", height=48, width=64, n_frames=20, seed=i) for i in range(n)]


def write_sweep(path: Path, scenes: list[dict], views: list[int], models: list[dict], configs: dict[str, Path],
                output: Path, **more) -> Path:
    sweep = {"name": "tiny", "output": str(output), "scenes": scenes, "views": views, "models": models,
             "dense": {"configs": [str(configs["dense"])]}, "tables": {"llff": "llff"}, "executor": "debug", **more}
    path.write_text(yaml.safe_dump(sweep, sort_keys=False))
    return path


def models(configs: dict[str, Path], names=("SimpleNeRF", "DS-NeRF")) -> list[dict]:
    files = {"SimpleNeRF": [str(configs["simplenerf"])],
             "DS-NeRF": [str(configs["simplenerf"]), str(configs["dsnerf"])]}
    return [{"name": name, "configs": files[name]} for name in names]


class KillOnceAt(Callback):
    """Kills its own process (SIGKILL: no checkpoint, no state update, as the OOM killer or a lost node would) when
    training reaches `step`, once: `marker` records that it did, so the rerun of the same config trains on."""

    def __init__(self, step: int, marker: str) -> None:
        self.step, self.marker = step, marker

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        import os
        import signal

        if trainer.global_step == self.step and not Path(self.marker).exists():
            Path(self.marker).touch()
            os.kill(os.getpid(), signal.SIGKILL)


class RequeueSignalAt(Callback):
    """Sends this process SLURM's requeue signal (SIGUSR1) when training reaches `step`, then stops the run as SLURM
    would once it has requeued the job (here by raising `Preempted`), once (`marker`)."""

    def __init__(self, step: int, marker: str) -> None:
        self.step, self.marker = step, marker

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        import os
        import signal

        if trainer.global_step == self.step and not Path(self.marker).exists():
            Path(self.marker).touch()
            os.kill(os.getpid(), signal.SIGUSR1)
            raise Preempted(f"preempted at step {self.step}")


class FailAt(Callback):
    """Raises RuntimeError("made to fail at step N") when training reaches `step`: a fit that fails with an error."""

    def __init__(self, step: int, marker: str) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            raise RuntimeError(f"made to fail at step {self.step}")


class Preempted(RuntimeError):
    pass


def callbacks_override(tmp: Path, name: str, callback: str, step: int, keep_warmup: bool = True) -> Path:
    """A config override whose trainer.callbacks (a list: replaced whole) are the tiny warm-up plus `callback`."""
    callbacks = []
    if keep_warmup:
        callbacks.append({"class_path": "simplenerf.run.callbacks.LossWeightSchedule",
                          "init_args": {"schedules": {k: [[0, 0.0], [1, 0.1]] for k in ("points", "views", "cfc")}}})
    callbacks.append({"class_path": f"tests.experiments.sweep_fixtures.{callback}",
                      "init_args": {"step": step, "marker": str(tmp / f"{name}.marker")}})
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"trainer": {"callbacks": callbacks}}))
    return path


def record_gpus(unit: dict) -> str:
    """A stand-in job: writes the CUDA_VISIBLE_DEVICES it was given and when it ran to <folder>/gpus.json."""
    import json
    import os
    import time

    start = time.time()
    time.sleep(1.0)
    Path(unit["folder"]).mkdir(parents=True, exist_ok=True)
    (Path(unit["folder"]) / "gpus.json").write_text(json.dumps(
        {"cuda": os.environ.get("CUDA_VISIBLE_DEVICES"), "start": start, "end": time.time()}))
    return "done"
