"""Tests of evaluation.evaluator: the Evaluator under a real Trainer (perfect and partly wrong predictions on the
synthetic scene), its helpers, and `test` through the real CLI, single-process and on 2 DDP processes."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import pytest
import torch

from simplenerf.data.batches import Frame
from simplenerf.data.llff import LLFFDataModule, load_llff_scene
from simplenerf.errors import DataError
from simplenerf.evaluation.evaluator import (
    ALL_METRICS,
    MASKED_METRICS,
    METRICS,
    Evaluator,
    export_visibility_masks,
    format_table,
    gather_rows,
    summarize,
    write_mask_png,
)
from simplenerf.evaluation.visibility import scene_visibility_masks
from simplenerf.metrics.scores import PSNR_CAP
from simplenerf.model.nerf import FrameRender
from tests.conftest import shared_dir
from tests.metrics.test_scores import assert_perfect_scores, lpips_weights
from tests.run.test_cli import run, run_args

SUMMARY_KEYS = ["scene", "n_views", "frames", *ALL_METRICS, "checkpoint", "git_commit", "config"]


class GroundTruthRenderer(L.LightningModule):
    """Renders each test frame as its ground truth (a perfect prediction), or as black outside `corrupt_outside`."""

    def __init__(self, corrupt_outside: dict[int, torch.Tensor] | None = None) -> None:
        super().__init__()
        self.corrupt_outside = corrupt_outside

    def test_step(self, batch: Frame, batch_idx: int) -> FrameRender:
        h, w = batch.height, batch.width
        rgb = batch.rgb.reshape(h, w, 3).clone()
        depth = batch.depth.reshape(h, w).clone() if batch.depth is not None else torch.ones(h, w)
        if self.corrupt_outside is not None:
            keep = self.corrupt_outside[batch.index]
            rgb[~keep] = 0.0
            depth[~keep] = 2.0 * depth[~keep]
        return FrameRender(rgb, depth, torch.ones(h, w), depth)


def run_test(root: Path, scene_dir: Path, module: L.LightningModule, **evaluator_args) -> Path:
    """Trainer.test of `module` on the 2-view synthetic scene; returns the test output folder."""
    dm = LLFFDataModule(scene_dir=str(scene_dir), n_views=2, factor=1)
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                        enable_checkpointing=False, enable_model_summary=False, default_root_dir=str(root),
                        callbacks=[Evaluator(**evaluator_args)])
    trainer.test(module, datamodule=dm)
    return root / "test"


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_perfect_prediction_scores_and_outputs(synthetic_scene, tmp_path) -> None:
    weights = lpips_weights()
    (tmp_path / "config.yaml").write_text("model: {}\n")  # as LightningCLI saves it into the log dir
    out = run_test(tmp_path, synthetic_scene, GroundTruthRenderer(), lpips_weights=str(weights))

    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == SUMMARY_KEYS
    assert summary["scene"] == synthetic_scene.name and summary["n_views"] == 2 and summary["frames"] == 3
    assert_perfect_scores(summary)
    assert summary["checkpoint"] is None  # tested with the module's own weights
    assert summary["config"] == str(out / "config.yaml") and (out / "config.yaml").read_text() == "model: {}\n"

    rows = read_csv(out / "metrics.csv")
    assert list(rows[0]) == ["frame", "index", *ALL_METRICS]
    assert [(r["frame"], r["index"]) for r in rows] == [("000", "0"), ("008", "8"), ("016", "16")]
    assert all(float(r["psnr"]) == PSNR_CAP and float(r["masked_psnr"]) == PSNR_CAP for r in rows)

    # The mask pictures are the visibility masks: white where evaluated.
    dm = LLFFDataModule(scene_dir=str(synthetic_scene), n_views=2, factor=1)
    dm.setup("test")
    masks = scene_visibility_masks(dm.scene.views, [6, 13], [0, 8, 16], progress=False)
    for index, name in ((0, "000"), (8, "008"), (16, "016")):
        picture = cv2.imread(str(out / "mask" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert picture.dtype == np.uint8 and picture.shape == (48, 64)
        assert np.array_equal(picture, np.where(masks[index].numpy(), 255, 0))
        assert (out / "rgb" / f"{name}.png").is_file() and (out / "depth" / f"{name}.npy").is_file()
    assert not (tmp_path / "test.partial").exists()


def test_masked_scores_use_each_frames_visibility_mask(synthetic_scene, tmp_path) -> None:
    dm = LLFFDataModule(scene_dir=str(synthetic_scene), n_views=2, factor=1)
    dm.setup("test")
    masks = scene_visibility_masks(dm.scene.views, [6, 13], [0, 8, 16], progress=False)
    assert all(0.5 < m.float().mean() < 1.0 for m in masks.values())
    # Wrong only outside each frame's mask: the masked scores are perfect, the full-frame ones are not.
    out = run_test(tmp_path, synthetic_scene, GroundTruthRenderer(corrupt_outside=masks), lpips=False)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["masked_psnr"] == PSNR_CAP and summary["masked_ssim"] == pytest.approx(1.0, abs=1e-12)
    assert summary["masked_depth_mae"] == 0.0 and summary["masked_depth_srocc"] == pytest.approx(1.0, abs=1e-12)
    assert summary["psnr"] < 30 and summary["ssim"] < 0.9 and summary["depth_mae"] > 0.05
    assert summary["lpips"] is None and summary["masked_lpips"] is None
    assert summary["config"] is None  # no config saved in the log dir


def test_scene_without_reference_depth_has_null_masked_and_depth_scores(synthetic_scene, tmp_path) -> None:
    scene = shutil.copytree(synthetic_scene, tmp_path / "scene", ignore=shutil.ignore_patterns("depths"))
    out = run_test(tmp_path, scene, GroundTruthRenderer(), lpips=False)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["psnr"] == PSNR_CAP and summary["scene"] == "scene"
    assert all(summary[name] is None for name in (*MASKED_METRICS, "depth_mae", "depth_srocc"))
    assert not any((out / "mask").iterdir())
    rows = read_csv(out / "metrics.csv")
    assert all(r["masked_psnr"] == "" for r in rows)  # csv writes None as an empty cell


def test_gather_rows_deduplicates_and_orders_by_index() -> None:
    rows = [{"frame": "016", "index": 16}, {"frame": "000", "index": 0}, {"frame": "016", "index": 16}]
    assert gather_rows(rows) == [{"frame": "000", "index": 0}, {"frame": "016", "index": 16}]


def test_summarize_averages_masked_scores_over_frames_with_a_mask() -> None:
    rows = [
        {"psnr": 20.0, "masked_psnr": 22.0, "lpips": None},
        {"psnr": 30.0, "masked_psnr": None, "lpips": None},
    ]
    means = summarize(rows)
    assert list(means) == list(ALL_METRICS)
    assert means["psnr"] == 25.0 and means["masked_psnr"] == 22.0 and means["lpips"] is None


def test_format_table() -> None:
    rows = [{"frame": "000", "psnr": 20.0, "ssim": 0.5}, {"frame": "008", "psnr": 22.0, "ssim": 0.7}]
    means = {"psnr": 21.0, "ssim": 0.6, "masked_psnr": None}
    lines = format_table(rows, means).splitlines()
    assert lines[0].split() == ["frame", *METRICS]
    assert lines[1].split() == ["000", "20.0000", "0.5000", "-", "-", "-"]
    assert lines[4].split() == ["mean", "21.0000", "0.6000", "-", "-", "-"]
    with_masked = format_table(rows[:1], {**means, "masked_psnr": 23.0}).splitlines()
    assert with_masked[0].split()[-1] == "masked_psnr" and with_masked[-1].split()[-1] == "23.0000"


def test_write_mask_png(tmp_path) -> None:
    mask = np.array([[True, False, True], [False, False, True]])
    write_mask_png(tmp_path / "m.png", mask)
    assert np.array_equal(cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_UNCHANGED), [[255, 0, 255], [0, 0, 255]])


def _lpips_env() -> tuple[list[str], dict]:
    lpips_file = shared_dir() / "data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz"
    if not lpips_file.exists():
        return ["--evaluation.lpips", "false"], {}
    return [], {"SIMPLENERF_LPIPS_WEIGHTS": str(lpips_file)}


def test_cli_test_writes_the_shared_format(tmp_path) -> None:
    """A 1-step fit and `test` through the real CLI on the synthetic scene (tiny model)."""
    extra, env = _lpips_env()
    run("fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--data.init_args.sparse_rays_per_batch", "0")
    proc = run("test", *run_args(tmp_path), "--ckpt_path", "last", *extra, env=env)
    out = tmp_path / "run" / "test"
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == SUMMARY_KEYS
    assert summary["scene"] == "seed0_96x128_20" and summary["n_views"] == 3 and summary["frames"] == 3
    for name in ("psnr", "ssim", "depth_mae", "depth_srocc", "masked_psnr", "masked_ssim", "masked_depth_mae",
                 "masked_depth_srocc"):
        assert isinstance(summary[name], float), name
    assert summary["masked_psnr"] < PSNR_CAP
    if not extra:
        assert isinstance(summary["lpips"], float) and isinstance(summary["masked_lpips"], float)
    assert summary["checkpoint"].endswith("last.ckpt")
    assert summary["config"] == str(out / "config.yaml") and "ckpt_path" in (out / "config.yaml").read_text()
    rows = read_csv(out / "metrics.csv")
    assert list(rows[0]) == ["frame", "index", *ALL_METRICS] and [r["index"] for r in rows] == ["0", "8", "16"]
    assert {p.name for p in (out / "mask").iterdir()} == {"000.png", "008.png", "016.png"}
    assert "masked_psnr" in proc.stdout and "mean" in proc.stdout  # the printed table


def test_ddp_test_on_two_cpu_processes_writes_each_frame_once(tmp_path) -> None:
    """3 test frames on 2 ranks: the sampler pads to 4, the outputs still hold 3 rows, written by rank 0."""
    run("fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--data.init_args.sparse_rays_per_batch", "0")
    proc = run("test", *run_args(tmp_path), "--ckpt_path", "last", "--evaluation.lpips", "false",
               "--trainer.accelerator", "cpu", "--trainer.devices", "2", "--trainer.strategy", "ddp")
    assert "Starting with 2 processes" in proc.stdout + proc.stderr
    out = tmp_path / "run" / "test"
    rows = read_csv(out / "metrics.csv")
    assert [r["index"] for r in rows] == ["0", "8", "16"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3 and isinstance(summary["masked_psnr"], float)
    assert {p.name for p in (out / "rgb").iterdir()} == {"000.png", "008.png", "016.png"}
    assert not (tmp_path / "run" / "test.partial").exists()


def test_export_visibility_masks(synthetic_scene, tmp_path) -> None:
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    fractions = export_visibility_masks(scene, tmp_path / "vis")
    masks = scene_visibility_masks(scene.views, [6, 13], [0, 8, 16], progress=False)
    assert list(fractions) == ["000", "008", "016"]
    for index, name in ((0, "000"), (8, "008"), (16, "016")):
        array = np.load(tmp_path / "vis" / f"{name}.npy")
        assert array.dtype == bool and np.array_equal(array, masks[index].numpy())
        assert fractions[name] == pytest.approx(array.mean())
        picture = cv2.imread(str(tmp_path / "vis" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(picture, np.where(array, 255, 0))

    scene.views.depths = None
    with pytest.raises(DataError, match=f"scene {synthetic_scene} has no reference depth.*`simplenerf export-depth`"):
        export_visibility_masks(scene, tmp_path / "none")
    assert not (tmp_path / "none").exists()


def test_visibility_masks_verb(synthetic_scene, tmp_path) -> None:
    import subprocess

    def tool(scene_dir: Path) -> subprocess.CompletedProcess:
        return run("visibility-masks", "--config", "configs/dsnerf.yaml", "--data.init_args.scene_dir", str(scene_dir),
                   "--data.init_args.factor", "1", "--trainer.default_root_dir", str(tmp_path / "run"), check=False)

    proc = tool(synthetic_scene)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert {p.name for p in (tmp_path / "run" / "visibility").iterdir()} == {
        f"{name}.{ext}" for name in ("000", "008", "016") for ext in ("png", "npy")
    }
    assert "008: " in proc.stdout and "% visible" in proc.stdout

    no_depth = shutil.copytree(synthetic_scene, tmp_path / "scene", ignore=shutil.ignore_patterns("depths"))
    proc = tool(no_depth)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith(f"simplenerf: error: scene {no_depth} has no reference")
