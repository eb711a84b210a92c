"""The real command line, end to end: fit, resume, test, print_config, and one-line errors on bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from tests.conftest import REPO, shared_dir

SMALL = [
    "--model.nerf.num_coarse", "8", "--model.nerf.num_fine", "8",
    *(f"--model.nerf.{f}.{k}={v}" for f in ("coarse", "fine") for k, v in (("num_layers", 2), ("width", 16))),
    *(f"--model.nerf.{f}.skip_layer=1" for f in ("coarse", "fine")), "--model.chunk", "4096",
    "--data.init_args.rays_per_batch", "64", "--data.init_args.sparse_rays_per_batch", "32",
    "--trainer.val_check_interval", "2", "--checkpoint.every_n_train_steps", "2",
]


def tiny_augmentations(tmp: Path) -> Path:
    """An override with the demo's augmentations at a tiny size (lists are replaced whole, so all of it)."""
    demo = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    augmentations = demo["model"]["augmentations"]
    for aug in augmentations:
        aug["init_args"]["field"]["init_args"].update(num_layers=2, width=16, skip_layer=1)
    path = tmp / "tiny_augmentations.yaml"
    path.write_text(yaml.safe_dump({"model": {"augmentations": augmentations}}))
    return path


def run(*args: str, env: dict | None = None, check: bool = True) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true", **(env or {})}
    proc = subprocess.run(
        [sys.executable, "-m", "simplenerf", *args], cwd=REPO, env=full_env, capture_output=True, text=True,
        timeout=600,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"exit {proc.returncode}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}")
    return proc


def run_args(tmp: Path) -> list[str]:
    """The demo config (SimpleNeRF on the synthetic scene, 96x128) shrunk to seconds, with its files in `tmp`."""
    return [
        "--config", "configs/demo.yaml", "--config", str(tiny_augmentations(tmp)), *SMALL,
        "--data.init_args.root", str(tmp / "data"), "--data.init_args.sparse_depth_cache", str(tmp / "cache"),
        "--trainer.default_root_dir", str(tmp / "run"), "--trainer.logger.init_args.save_dir", str(tmp / "run"),
    ]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A 4-step fit, resumed to 6 steps with --ckpt_path last."""
    tmp = tmp_path_factory.mktemp("cli")
    run("fit", *run_args(tmp), "--trainer.max_steps", "4")
    run("fit", *run_args(tmp), "--trainer.max_steps", "6", "--ckpt_path", "last")
    return tmp


def test_fit_writes_checkpoints_and_resumes(trained):
    ckpts = trained / "run" / "checkpoints"
    assert {"step000002.ckpt", "step000004.ckpt", "step000006.ckpt", "last.ckpt"} <= {p.name for p in ckpts.iterdir()}
    last = torch.load(ckpts / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 6  # resumed from step 4, not restarted
    assert (trained / "run" / "wandb").is_dir()  # the default logger ran, offline
    # SimpleNeRF's pieces were trained, and validation saved the reliability masks of the first train view.
    assert "augmentations.0.field.trunk.0.weight" in last["state_dict"]
    assert {"mask_points_step000002.png", "mask_views_step000002.png", "mask_cfc_step000002.png"} <= {
        p.name for p in (trained / "run" / "val").iterdir()
    }
    # ...and the validation renders of the validation view (simplenerf.viz.renders.ValidationRenders, a CLI default).
    assert {f"step000004_{kind}.png" for kind in ("rgb", "depth", "accumulation", "error")} <= {
        p.name for p in (trained / "run" / "val").iterdir()
    }


def test_validate_reports_psnr(trained):
    out = run("validate", *run_args(trained), "--ckpt_path", "last").stdout
    assert "val/psnr" in out


def test_test_writes_metrics_and_renders(trained):
    lpips_file = shared_dir() / "data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz"
    extra = [] if lpips_file.exists() else ["--evaluation.lpips", "false"]
    run("test", *run_args(trained), "--ckpt_path", "last", *extra, env={"SIMPLENERF_LPIPS_WEIGHTS": str(lpips_file)})
    out = trained / "run" / "test"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3  # frames 0, 8, 16 of 20
    for key in ("psnr", "ssim", "depth_mae", "depth_srocc"):
        assert isinstance(summary[key], float)
    assert 0 < summary["psnr"] < 100 and -1 <= summary["ssim"] <= 1 and summary["depth_mae"] >= 0
    if lpips_file.exists():
        assert 0 <= summary["lpips"] <= 1
    rows = (out / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("frame,index,psnr,ssim,lpips,depth_mae,depth_srocc") and len(rows) == 4
    assert {p.name for p in (out / "rgb").iterdir()} == {"000.png", "008.png", "016.png"}
    assert (out / "depth" / "008.npy").is_file() and (out / "depth" / "008.png").is_file()
    run_info = json.loads((out / "run.json").read_text())
    assert run_info["checkpoint"].endswith("last.ckpt")
    assert not (trained / "run" / "test.partial").exists()


def test_missing_lpips_weights_stop_test_before_writing(trained, tmp_path):
    (trained / "run" / "test").mkdir(exist_ok=True)
    marker = trained / "run" / "test" / "marker"
    marker.write_text("earlier results")
    env = {"SIMPLENERF_LPIPS_WEIGHTS": str(tmp_path / "missing.npz"), "TORCH_HOME": str(tmp_path / "hub")}
    proc = run("test", *run_args(trained), "--ckpt_path", "last", env=env, check=False)
    assert proc.returncode == 2
    assert "simplenerf: error:" in proc.stderr and "SIMPLENERF_LPIPS_WEIGHTS" in proc.stderr
    assert marker.read_text() == "earlier results"


def test_bad_scene_is_one_line_error(tmp_path):
    proc = run(
        "fit", "--config", "configs/llff.yaml", "--data.init_args.scene_dir", str(tmp_path / "nope"),
        "--trainer.default_root_dir", str(tmp_path / "run"), check=False,
    )
    assert proc.returncode == 2
    expected = f"simplenerf: error: scene directory {tmp_path / 'nope'} does not exist"
    assert proc.stderr.strip().splitlines()[-1] == expected
    assert "Traceback" not in proc.stderr


def test_too_many_views_is_one_line_error(tmp_path):
    proc = run("fit", *run_args(tmp_path), "--data.init_args.n_views", "30", check=False)
    assert proc.returncode == 2
    assert "n_views=30 is not possible: the train pool has 17 frames" in proc.stderr


def test_print_config_is_commented_and_reloadable(tmp_path):
    printed = run("fit", "--config", "configs/demo.yaml", "--print_config=comments").stdout
    assert "# lambda_1, weight of the colour loss." in printed  # argument docs become comments
    config = tmp_path / "printed.yaml"
    config.write_text(printed)
    assert yaml.safe_load(printed)["model"]["nerf"]["init_args"]["coarse"]["init_args"]["width"] == 64
    reprinted = run("fit", "--config", str(config), "--print_config").stdout
    original = run("fit", "--config", "configs/demo.yaml", "--print_config").stdout
    assert yaml.safe_load(reprinted) == yaml.safe_load(original)


def test_help_shows_argument_docs():
    out = run("fit", "--help").stdout
    assert "lambda_1, weight of the colour loss" in out


def test_user_augmentation_plugs_in_by_class_path(tmp_path):
    override = tmp_path / "user_aug.yaml"
    override.write_text(
        "model:\n"
        "  augmentations:\n"
        "    - class_path: tests.custom_augmentation.LowPassPointsAugmentation\n"
        "      init_args: {bands: 2, width: 16, num_layers: 2}\n"
        "  coarse_fine_mask: {class_path: simplenerf.method.reliability.PatchReprojectionMask}\n"
        "trainer:\n"
        "  callbacks:\n"
        "    - class_path: simplenerf.callbacks.LossWeightSchedule\n"
        "      init_args: {schedules: {lowpass: [[0, 0.0], [1, 0.1]]}}\n"
    )
    run("fit", *run_args(tmp_path), "--config", str(override), "--trainer.max_steps", "2")
    state = torch.load(tmp_path / "run/checkpoints/last.ckpt", map_location="cpu", weights_only=False)["state_dict"]
    assert state["augmentations.0.field.trunk.0.weight"].shape == (16, 15)  # gamma(p, 0, 2): 15 inputs


def test_unreadable_image_stops_before_anything_is_written(synthetic_scene, tmp_path):
    import shutil

    scene = shutil.copytree(synthetic_scene, tmp_path / "scene")
    (scene / "images" / "005.png").write_bytes(b"truncated")
    proc = run(
        "fit", "--config", "configs/dsnerf.yaml", "--data.init_args.scene_dir", str(scene),
        "--data.init_args.factor", "1", "--trainer.default_root_dir", str(tmp_path / "run"),
        "--trainer.logger.init_args.save_dir", str(tmp_path / "run"), check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        f"simplenerf: error: cannot read image {scene / 'images' / '005.png'} (missing, truncated or not an image)"
    )
    assert not (tmp_path / "run" / "wandb").exists() and not (tmp_path / "run" / "checkpoints").exists()


def test_fit_without_a_logger(tmp_path):
    args = run_args(tmp_path)
    assert args[-2] == "--trainer.logger.init_args.save_dir"
    run("fit", *args[:-2], "--trainer.logger", "false", "--trainer.max_steps", "1")
    assert (tmp_path / "run/checkpoints/last.ckpt").is_file() and not (tmp_path / "run/wandb").exists()
