"""Evaluation outputs of `test` (and renders of `predict`): images, depths, per-frame CSV and a summary JSON.

Everything is written to `<dir>.partial/` first and moved into place only when the run completes, so a crash or a
bad input never leaves half-written files over the results of an earlier run.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch

from simplenerf.lpips import LPIPS
from simplenerf.metrics import FrameMetrics, evaluate_frame

METRICS = ("psnr", "ssim", "lpips", "depth_mae", "depth_srocc")


def colorize_depth(depth: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """An 8-bit RGB picture [H, W, 3] of a depth map [H, W]: turbo colours of inverse depth (near = warm)."""
    inv = 1.0 / np.maximum(depth, 1e-6)
    lo = float(np.percentile(inv, 1)) if lo is None else lo
    hi = float(np.percentile(inv, 99)) if hi is None else hi
    scaled = np.clip((inv - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return cv2.cvtColor(cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Writes an RGB image [H, W, 3] (uint8, or float in [0, 1])."""
    if rgb.dtype != np.uint8:
        rgb = np.round(np.clip(rgb, 0.0, 1.0) * 255).astype(np.uint8)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")


def git_commit() -> str | None:
    """The commit of the code being run, if it runs from a git checkout."""
    try:
        root = Path(__file__).resolve().parent
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def summarize(rows: list[dict]) -> dict[str, float | None]:
    """Mean of each metric over frames (None where no frame has it)."""
    summary = {}
    for name in METRICS:
        values = [r[name] for r in rows if r.get(name) is not None]
        summary[name] = float(np.mean(values)) if values else None
    return summary


class Evaluator(L.Callback):
    """Scores and saves every rendered test frame; saves renders of `predict`.

    Output folder (default `<trainer.default_root_dir>/test`): `rgb/<frame>.png`, `depth/<frame>.npy` (metric depth,
    scene units), `depth/<frame>.png` (colourised), `metrics.csv` (one row per frame) and `summary.json` (means and
    provenance).
    """

    def __init__(self, output_dir: str | None = None, lpips: bool = True, lpips_weights: str | None = None) -> None:
        """
        Args:
            output_dir: where test outputs go; default <trainer.default_root_dir>/test (predict: .../predict).
            lpips: compute LPIPS (AlexNet, v0.1). Needs the AlexNet trunk weights, see lpips_weights.
            lpips_weights: AlexNet trunk weights (torchvision .pth or the LPIPS .npz); None: the
                SIMPLENERF_LPIPS_WEIGHTS environment variable, then the torch hub cache, then a download.
        """
        self.output_dir, self.use_lpips, self.lpips_weights = output_dir, lpips, lpips_weights
        self.lpips_net: LPIPS | None = None
        self.rows: list[dict] = []
        self._final: Path | None = None
        self._partial: Path | None = None

    def check_inputs(self, stage: str) -> None:
        """Loads LPIPS for `test`: missing weights stop the run before anything is rendered or written."""
        if stage == "test" and self.use_lpips and self.lpips_net is None:
            self.lpips_net = LPIPS.from_weights(self.lpips_weights, allow_download=True)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage not in ("test", "predict"):
            return
        self.check_inputs(stage)
        name = "test" if stage == "test" else "predict"
        self._final = Path(self.output_dir or os.path.join(trainer.default_root_dir, name))
        self._partial = self._final.with_name(self._final.name + ".partial")
        if trainer.is_global_zero:
            shutil.rmtree(self._partial, ignore_errors=True)
            (self._partial / "rgb").mkdir(parents=True)
            (self._partial / "depth").mkdir(parents=True)
        self.rows = []

    def _save_frame(self, name: str, pred: dict[str, torch.Tensor]) -> None:
        assert self._partial is not None
        depth = pred["depth"].float().cpu().numpy()
        write_png(self._partial / "rgb" / f"{name}.png", pred["rgb"].float().cpu().numpy())
        np.save(self._partial / "depth" / f"{name}.npy", depth)
        write_png(self._partial / "depth" / f"{name}.png", colorize_depth(depth))

    def on_test_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        target = batch["rgb"].reshape(outputs["rgb"].shape)
        gt_depth = batch["depth"].reshape(outputs["depth"].shape) if "depth" in batch else None
        if self.lpips_net is not None:
            self.lpips_net.to(outputs["rgb"].device)
        metrics: FrameMetrics = evaluate_frame(outputs["rgb"], target, outputs["depth"], gt_depth, self.lpips_net)
        row = {"frame": batch["name"], "index": int(batch["index"]), **metrics.as_dict()}
        self.rows.append(row)
        for key, value in metrics.as_dict().items():
            if value is not None and math.isfinite(value):
                pl_module.log(f"test/{key}", value, batch_size=1)
        self._save_frame(batch["name"], outputs)

    def on_predict_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        self._save_frame(batch["name"], outputs)

    def _commit_outputs(self, trainer: L.Trainer, extra: dict) -> None:
        assert self._partial is not None and self._final is not None
        if not trainer.is_global_zero:
            return
        with open(self._partial / "run.json", "w") as f:
            json.dump({"written": datetime.now(timezone.utc).isoformat(), "git_commit": git_commit(), **extra}, f,
                      indent=2)
        backup = self._final.with_name(self._final.name + ".previous")
        if self._final.exists():
            shutil.rmtree(backup, ignore_errors=True)
            self._final.rename(backup)
        self._partial.rename(self._final)
        shutil.rmtree(backup, ignore_errors=True)

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        assert self._partial is not None and self._final is not None
        with open(self._partial / "metrics.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["frame", "index", *METRICS])
            writer.writeheader()
            writer.writerows(self.rows)
        summary = {"frames": len(self.rows), **summarize(self.rows)}
        with open(self._partial / "summary.json", "w") as f:
            json.dump(summary, f, indent=2)
        self._commit_outputs(trainer, {"checkpoint": trainer.ckpt_path, "stage": "test"})
        print(f"test outputs: {self._final}\n" + json.dumps(summary, indent=2))

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._commit_outputs(trainer, {"checkpoint": trainer.ckpt_path, "stage": "predict"})
