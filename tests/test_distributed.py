"""Distributed training on CPU (DDP over gloo): ranks draw different rays, and `fit` runs through the real CLI, also
with the paper config's shape (parts of `rays_per_backward` rays, sparse depth, augmentations, L_cfc); and a fit
with a mixed-precision plugin."""

from __future__ import annotations

import itertools
from pathlib import Path

import torch
import yaml

from simplenerf.data import datasets
from simplenerf.data.llff import load_llff_scene, subset
from tests.conftest import REPO
from tests.run.test_cli import run, run_args, shrink


def first_batches(views, rank: int, monkeypatch, n: int = 3) -> list:
    """The random rays (`RayBatch`) of the first n training batches of a rank."""
    monkeypatch.setattr(datasets, "_rank", lambda: rank)
    return [b.random for b in itertools.islice(iter(datasets.RandomRays(views, 64, near=1.0, seed=0)), n)]


def test_each_rank_draws_its_own_rays(synthetic_scene, monkeypatch):
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = subset(scene.views, scene.split.train)
    rank0 = first_batches(views, 0, monkeypatch)
    rank1 = first_batches(views, 1, monkeypatch)
    again0 = first_batches(views, 0, monkeypatch)
    for a, b, c in zip(rank0, rank1, again0, strict=True):
        assert torch.equal(a.uv, c.uv) and torch.equal(a.view, c.view)  # reproducible per rank
        pixels_a = set(zip(a.view.tolist(), map(tuple, a.uv.tolist()), strict=True))
        pixels_b = set(zip(b.view.tolist(), map(tuple, b.uv.tolist()), strict=True))
        assert len(pixels_a & pixels_b) < 8  # 64 of ~6000 pixels each: independent draws share a handful at most


def test_ddp_fit_on_two_cpu_processes(tmp_path):
    proc = run("fit", *run_args(tmp_path), "--trainer.max_steps", "3", "--trainer.accelerator", "cpu",
               "--trainer.devices", "2", "--trainer.strategy", "ddp")
    assert "Starting with 2 processes" in proc.stdout + proc.stderr
    last = torch.load(tmp_path / "run/checkpoints/last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3
    assert (tmp_path / "run/val/mask_points_step000002.png").is_file()  # written once, by rank 0


def paper_shape(tmp: Path) -> list[str]:
    """configs/llff.yaml's model shrunk, every term on from step 0, on the demo's synthetic scene (3 views, 96x128):
    64 random + 32 sparse rays a step in parts of at most 24 rays (3 + 2 parts)."""
    llff, demo = (yaml.safe_load((REPO / "configs" / f"{name}.yaml").read_text()) for name in ("llff", "demo"))
    data = demo["data"]
    data["init_args"].update(root=str(tmp / "data"), sparse_depth_cache=str(tmp / "cache"), rays_per_batch=64,
                             sparse_rays_per_batch=32)
    override = {
        "model": {"nerf": shrink(llff["model"]["nerf"]), "augmentations": shrink(llff["model"]["augmentations"]),
                  "rays_per_backward": 24, "chunk": 4096},
        "data": data,
        "trainer": {"callbacks": [{"class_path": "simplenerf.run.callbacks.LossWeightSchedule", "init_args": {
            "schedules": {name: [[0, 0.1]] for name in ("points", "views", "cfc")}}}]},
    }
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / "paper_shape.yaml").write_text(yaml.safe_dump(override))
    return ["--config", "configs/llff.yaml", "--config", str(tmp / "paper_shape.yaml"),
            "--trainer.default_root_dir", str(tmp / "run"), "--trainer.logger", "false",
            "--trainer.val_check_interval", "1000", "--checkpoint.every_n_train_steps", "1000",
            "--trainer.callbacks+=tests.custom_callbacks.StepRecord",
            "--trainer.callbacks.init_args.path", str(tmp / "steps.txt")]


def test_paper_config_shape_trains_with_ddp_and_the_ranks_stay_equal(tmp_path):
    """Parts of 24 rays, sparse depth, augmentations and L_cfc with DDP on 2 processes: the ranks draw different rays,
    so only gradients averaged over the ranks keep their weights equal after every step."""
    proc = run("fit", *paper_shape(tmp_path), "--trainer.max_steps", "3", "--trainer.accelerator", "cpu",
               "--trainer.devices", "2", "--trainer.strategy", "ddp")
    assert "Starting with 2 processes" in proc.stdout + proc.stderr
    rows = [line.split() for line in (tmp_path / "steps.txt").read_text().splitlines()]
    by_rank = {rank: [(step, checksum) for r, step, checksum, _ in rows if r == rank] for rank in ("0", "1")}
    assert [step for step, _ in by_rank["0"]] == ["1", "2", "3"] and by_rank["0"] == by_rank["1"]
    terms = {"train/loss_color", "train/loss_sparse_depth", "train/loss_points", "train/loss_views", "train/loss_cfc"}
    assert all(set(row[3].split(",")) == terms for row in rows)
    last = torch.load(tmp_path / "run/checkpoints/last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3


def test_paper_config_shape_trains_in_bf16(tmp_path):
    """The bf16-mixed precision plugin with parts: 3 optimiser steps, every logged loss finite."""
    run("fit", *paper_shape(tmp_path), "--trainer.max_steps", "3", "--trainer.precision", "bf16-mixed")
    rows = [line.split() for line in (tmp_path / "steps.txt").read_text().splitlines()]
    assert [row[1] for row in rows] == ["1", "2", "3"]
    last = torch.load(tmp_path / "run/checkpoints/last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3 and all(torch.isfinite(v).all() for v in last["state_dict"].values())
