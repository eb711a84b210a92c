"""Distributed training on CPU (DDP over gloo): ranks draw different rays, and `fit` runs through the real CLI."""

from __future__ import annotations

import itertools

import torch

from simplenerf.data import datasets
from simplenerf.data.llff import load_llff_scene, subset
from tests.test_cli import run, run_args


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
