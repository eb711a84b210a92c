"""A run you can trust: every bad input of issue 12's table stops the real command line with one error line, exit
status 2 and nothing created or overwritten; a resume falls back to a readable checkpoint; a NaN loss stops training
and keeps the last good checkpoint. One test per row of the table."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from tests.run.test_cli import REPO, SIZES, run, run_args, shrink

ERROR = "simplenerf: error: "


def error_lines(proc) -> list[str]:
    """What a stopped command printed on stderr, for an exact comparison."""
    return proc.stderr.strip().splitlines()


@pytest.fixture(scope="module")
def shared(tmp_path_factory) -> Path:
    """The generated scene and SfM cache every run of this module shares, and a 4-step run whose checkpoints
    (steps 2 and 4, last.ckpt = step 4) and config.yaml the tests copy."""
    tmp = tmp_path_factory.mktemp("trust")
    run("fit", *run_args(tmp / "base", tmp), "--trainer.max_steps", "4")
    return tmp


def run_folder(tmp: Path, shared: Path) -> Path:
    """A copy of the shared 4-step run's checkpoints and config.yaml in `tmp/run`."""
    run_dir = tmp / "run"
    shutil.copytree(shared / "base" / "run" / "checkpoints", run_dir / "checkpoints")
    shutil.copyfile(shared / "base" / "run" / "config.yaml", run_dir / "config.yaml")
    return run_dir


def llff_copy(synthetic_scene: Path, tmp: Path) -> Path:
    return Path(shutil.copytree(synthetic_scene, tmp / "scene"))


def llff_fit(scene: Path, tmp: Path, *extra: str):
    """fit of the DS-NeRF config on an LLFF-layout scene at factor 1, run folder tmp/run."""
    return run(
        "fit", "--config", "configs/dsnerf.yaml", "--data.init_args.scene_dir", str(scene),
        "--data.init_args.factor", "1", "--trainer.default_root_dir", str(tmp / "run"),
        "--trainer.logger.init_args.save_dir", str(tmp / "run"), *extra, check=False,
    )


# | images of mixed sizes in images_N/ | one line naming the odd file and its size |
def test_mixed_image_sizes_name_the_odd_file(synthetic_scene, tmp_path):
    scene = llff_copy(synthetic_scene, tmp_path)
    odd = scene / "images" / "007.png"
    cv2.imwrite(str(odd), np.zeros((24, 32, 3), np.uint8))
    proc = llff_fit(scene, tmp_path)
    assert proc.returncode == 2
    assert error_lines(proc) == [f"{ERROR}{odd} is 32x24 but 000.png is 64x48: all images must have the same size"]
    # | run folder before the input checks | nothing created until the inputs pass |
    assert not (tmp_path / "run").exists()


# | test --ckpt_path last with no checkpoint | one line, exit 2, nothing written |
def test_test_without_a_checkpoint_refuses(shared, tmp_path):
    earlier = tmp_path / "run" / "test"
    earlier.mkdir(parents=True)
    (earlier / "summary.json").write_text("earlier results")
    proc = run("test", *run_args(tmp_path, shared), "--ckpt_path", "last", "--evaluation.lpips", "false", check=False)
    assert proc.returncode == 2
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert error_lines(proc) == [
        f"{ERROR}no checkpoint to test: {last} does not exist (train the run with fit first, or give --ckpt_path FILE)"
    ]
    assert sorted(p.name for p in (tmp_path / "run").rglob("*")) == ["summary.json", "test"]
    assert (earlier / "summary.json").read_text() == "earlier results"
    # Without --ckpt_path at all, test would score an untrained model: refused the same way.
    proc = run("test", *run_args(tmp_path, shared), "--evaluation.lpips", "false", check=False)
    assert proc.returncode == 2
    assert error_lines(proc) == [f"{ERROR}test needs trained weights: add --ckpt_path last (the run's {last}) or "
                                 "--ckpt_path FILE"]
    # Refused once it holds the lock of a run folder it created: the folder (and its parents) are removed again.
    fresh = tmp_path / "new" / "run"
    proc = run("test", *run_args(tmp_path, shared), "--ckpt_path", "last", "--evaluation.lpips", "false",
               "--trainer.default_root_dir", str(fresh), check=False)
    assert proc.returncode == 2 and error_lines(proc)[0].startswith(f"{ERROR}no checkpoint to test: ")
    assert not (tmp_path / "new").exists()


# | test/fit with a missing, truncated or incompatible checkpoint | one line naming the file; config.yaml untouched |
def test_unusable_checkpoints_are_one_line_errors(shared, tmp_path):
    run_dir = run_folder(tmp_path, shared)
    config = (run_dir / "config.yaml").read_bytes()
    last = run_dir / "checkpoints" / "last.ckpt"
    args = [*run_args(tmp_path, shared), "--evaluation.lpips", "false"]

    missing = tmp_path / "nope.ckpt"
    proc = run("test", *args, "--ckpt_path", str(missing), check=False)
    assert proc.returncode == 2 and error_lines(proc) == [f"{ERROR}checkpoint {missing} does not exist"]

    checkpoint = torch.load(last, map_location="cpu", weights_only=False)
    name = next(iter(checkpoint["state_dict"]))
    shape = tuple(checkpoint["state_dict"][name].shape)
    checkpoint["state_dict"][name] = torch.zeros(3, 5)
    other = tmp_path / "other_width.ckpt"
    torch.save(checkpoint, other)
    proc = run("test", *args, "--ckpt_path", str(other), check=False)
    assert proc.returncode == 2 and error_lines(proc) == [
        f"{ERROR}checkpoint {other} does not fit the model: {name} is (3, 5) in it but {shape} in the model (was it "
        "trained with another config?)"
    ]

    last.write_bytes(last.read_bytes()[:1000])
    proc = run("test", *args, "--ckpt_path", "last", check=False)
    assert proc.returncode == 2
    [line] = error_lines(proc)
    assert line.startswith(f"{ERROR}cannot read checkpoint {last} (truncated or not a checkpoint: ")
    assert (run_dir / "config.yaml").read_bytes() == config and not (run_dir / "test").exists()


# | fit --ckpt_path last with an unreadable last.ckpt | falls back to the newest readable checkpoint and says so |
def test_resume_falls_back_to_the_newest_readable_checkpoint(shared, tmp_path):
    run_dir = run_folder(tmp_path, shared)
    last = run_dir / "checkpoints" / "last.ckpt"
    last.write_bytes(b"")
    proc = run("fit", *run_args(tmp_path, shared), "--trainer.max_steps", "6", "--ckpt_path", "last")
    notices = [line for line in error_lines(proc) if line.startswith("simplenerf: ")
               and not line.startswith("simplenerf: CPU ")]  # the machine's line (run.hardware) is not a notice
    step4 = run_dir / "checkpoints" / "step000004.ckpt"
    assert len(notices) == 1
    assert notices[0].startswith(f"simplenerf: cannot read checkpoint {last} (truncated or not a checkpoint: ")
    assert notices[0].endswith(f"; resuming from {step4} (step 4), the newest readable checkpoint, instead")
    assert torch.load(last, map_location="cpu", weights_only=False)["global_step"] == 6


# | fit resumed with another width | one line naming the file; config.yaml of the run untouched |
def test_resume_with_another_width_is_one_line_error(shared, tmp_path):
    run_dir = run_folder(tmp_path, shared)
    config = (run_dir / "config.yaml").read_bytes()
    model = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())["model"]
    wide = tmp_path / "wide.yaml"
    wide.write_text(yaml.safe_dump({"model": {"nerf": shrink(model["nerf"], {**SIZES, "width": 24})}}))
    proc = run("fit", *run_args(tmp_path, shared), "--config", str(wide), "--trainer.max_steps", "6",
               "--ckpt_path", "last", check=False)
    assert proc.returncode == 2
    [line] = error_lines(proc)
    last = run_dir / "checkpoints" / "last.ckpt"
    assert line.startswith(f"{ERROR}checkpoint {last} does not fit the model: ")
    shapes = r" is \(16(, \d+)?\) in it but \(24(, \d+)?\) in the model \(was it trained with another config\?\)"
    assert re.search(shapes, line)
    assert line.endswith(f"; no other checkpoint in {run_dir / 'checkpoints'} can be resumed either")
    assert (run_dir / "config.yaml").read_bytes() == config and not (run_dir / "wandb").exists()


# | NaN/inf or zero near bound in poses_bounds.npy | one line naming the file and the frame |
def test_bad_bounds_name_the_file_and_the_frame(synthetic_scene, tmp_path):
    scene = llff_copy(synthetic_scene, tmp_path)
    path = scene / "poses_bounds.npy"
    poses_bounds = np.load(path)
    far = poses_bounds[3, 16]
    poses_bounds[3, 15] = 0.0
    np.save(path, poses_bounds)
    proc = llff_fit(scene, tmp_path)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}{path}: frame 3 (003.png) has near bound 0 and far bound {far:g}; they must be 0 < near < far"
    ]
    assert not (tmp_path / "run").exists()


# | frame files whose names do not sort in frame order (img2, img10) | stop with one line |
def test_names_out_of_frame_order_stop(synthetic_scene, tmp_path):
    scene = llff_copy(synthetic_scene, tmp_path)
    for i in range(20):
        (scene / "images" / f"{i:03d}.png").rename(scene / "images" / f"img{i}.png")
    proc = llff_fit(scene, tmp_path)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}{scene / 'images'}: image names sort differently as text and by number (as text img10.png comes "
        "before img2.png), so which pose of poses_bounds.npy belongs to which image is ambiguous; rename them with "
        "zero-padded numbers (e.g. img002.png)"
    ]


# | fit again into a run folder that has checkpoints, without --ckpt_path | refuse, unless --overwrite true |
def test_fit_into_a_run_with_checkpoints_refuses_unless_overwrite(shared, tmp_path):
    run_dir = run_folder(tmp_path, shared)
    folder = run_dir / "checkpoints"
    last = (folder / "last.ckpt").read_bytes()
    proc = run("fit", *run_args(tmp_path, shared), "--trainer.max_steps", "2", check=False)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}{folder} already has checkpoints (last.ckpt, step000002.ckpt, step000004.ckpt): resume that run "
        "with --ckpt_path last, choose another folder with --trainer.default_root_dir, or start afresh with "
        "--overwrite true"
    ]
    assert (folder / "last.ckpt").read_bytes() == last and not (run_dir / "wandb").exists()
    proc = run("fit", *run_args(tmp_path, shared), "--trainer.max_steps", "2", "--overwrite", "true")
    assert f"simplenerf: --overwrite: deleted the 3 checkpoints of the earlier run in {folder}" in error_lines(proc)
    assert sorted(p.name for p in folder.iterdir()) == ["last.ckpt", "step000002.ckpt"]
    assert torch.load(folder / "last.ckpt", map_location="cpu", weights_only=False)["global_step"] == 2


# | n_views 1 with SimpleNeRF's masks | one line |
def test_one_view_with_reliability_masks_is_one_line_error(shared, tmp_path):
    proc = run("fit", *run_args(tmp_path, shared), "--data.init_args.n_views", "1", check=False)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}1 train view is too few for this model: its augmentations and coarse_fine_mask compare depth across "
        "train views and need at least 2 (use n_views >= 2, or a model without them, e.g. configs/dsnerf.yaml)"
    ]
    assert not (tmp_path / "run").exists()


# | read-only output folder | one line |
def test_read_only_run_folder_is_one_line_error(synthetic_scene, tmp_path):
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    os.chmod(read_only, 0o555)
    command = [sys.executable, "-m", "simplenerf", "fit", "--config", "configs/dsnerf.yaml",
               "--data.init_args.scene_dir", str(synthetic_scene), "--data.init_args.factor", "1",
               "--data.init_args.sparse_rays_per_batch", "0", "--trainer.default_root_dir", str(read_only / "run"),
               "--trainer.logger.init_args.save_dir", str(read_only / "run")]
    if os.geteuid() == 0:  # root writes anywhere unless it gives up the capability to override permissions
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: a read-only folder cannot be made")
        command = ["setpriv", "--bounding-set=-dac_override", "--inh-caps=-dac_override", *command]
    env = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true"}
    proc = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert error_lines(proc) == [f"{ERROR}cannot write to the run folder {read_only / 'run'}: Permission denied"]
    assert list(read_only.iterdir()) == []


# | unknown option / mistyped class_path | the one error line first, then at most a hint |
def test_parser_errors_are_one_line_and_a_hint():
    proc = run("fit", "--config", "configs/demo.yaml", "--trainer.max_stepz", "4", check=False)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}unrecognized arguments: --trainer.max_stepz 4",
        "hint: did you mean --trainer.max_steps? (`simplenerf fit --help` lists every option)",
    ]
    proc = run("fit", "--config", "configs/demo.yaml", "--data", "simplenerf.data.synthetic.SynteticDataModule",
               check=False)
    assert proc.returncode == 2
    assert error_lines(proc) == [
        f"{ERROR}--data: class_path simplenerf.data.synthetic.SynteticDataModule: module 'simplenerf.data.synthetic' "
        "has no attribute 'SynteticDataModule'",
        "hint: did you mean simplenerf.data.synthetic.SyntheticDataModule? (`simplenerf fit --help` lists every "
        "option)",
    ]
    proc = run("fit", "--config", "configs/demo.yaml", "--data.init_args.n_vews", "2", check=False)
    assert proc.returncode == 2
    [line, hint] = error_lines(proc)
    assert line.startswith(f"{ERROR}--data") and "n_vews" in line
    assert hint == "hint: did you mean n_views? (`simplenerf fit --help` lists every option)"


# | a NaN loss during training | stop with one line and keep the last good checkpoint |
def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(shared, tmp_path):
    poison = tmp_path / "poison.yaml"
    poison.write_text(
        "trainer:\n"
        "  callbacks:\n"
        "    - class_path: tests.custom_callbacks.PoisonLossAt\n"
        "      init_args: {step: 5}\n"
    )
    proc = run("fit", *run_args(tmp_path, shared), "--config", str(poison), "--trainer.max_steps", "8", check=False)
    assert proc.returncode == 1
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert error_lines(proc)[-1] == (
        f"{ERROR}training stopped at step 6: the loss is nan (non-finite: color); the checkpoints written before it "
        f"are kept (resume from {last}, step 4)"
    )
    assert "Traceback" not in proc.stderr
    checkpoint = torch.load(last, map_location="cpu", weights_only=False)
    assert checkpoint["global_step"] == 4
    assert all(torch.isfinite(t).all() for t in checkpoint["state_dict"].values() if t.is_floating_point())
    assert "step 5/8 (62%)" in proc.stdout and "step 6/8" not in proc.stdout
