"""Shared fixtures: the read-only project data (../shared) and a small generated synthetic scene."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from simplenerf.synthetic.generate import make_synthetic_scene

REPO = Path(__file__).resolve().parents[1]

# Tests never talk to W&B servers and keep its console output short.
os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")

# `-n N` (pytest-xdist): N worker processes share the cores, so each, and every CLI process it starts, uses its share
# of them (one thread each with two workers on two cores) instead of one OpenMP thread per core: oversubscribed
# OpenMP threads wait on each other (docs/testing.md: 14-15% less time). OMP_NUM_THREADS set outside wins.
if (_workers := int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))) > 1:
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // _workers)))
    torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


@pytest.fixture
def two_threads():
    """torch with 2 intra-op threads for one test (xdist workers may run with 1), restored after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)


def shared_dir() -> Path:
    """The project's shared data: $SIMPLENERF_SHARED, else ../shared next to the repository."""
    return Path(os.environ.get("SIMPLENERF_SHARED", REPO.parent / "shared"))


def require_shared(relative: str) -> Path:
    """A path under the shared data, or skip the test saying what is missing."""
    path = shared_dir() / relative
    if not path.exists():
        pytest.skip(f"needs {path} (set SIMPLENERF_SHARED to the folder holding data/)")
    return path


# `fit` checks the LPIPS weights its test will need before training: the shared data's copy, unless a test names
# other weights (or none) or the environment does.
if (_lpips_weights := shared_dir() / "data" / "lpips" / "alexnet_trunk_and_lpips_lin_v0.1.npz").is_file():
    os.environ.setdefault("SIMPLENERF_LPIPS_WEIGHTS", str(_lpips_weights))


@pytest.fixture(scope="session")
def synthetic_scene(tmp_path_factory) -> Path:
    """A 20-frame synthetic scene at 48x64 (factor 1) with exact depth."""
    return make_synthetic_scene(tmp_path_factory.mktemp("synthetic") / "scene", height=48, width=64, n_frames=20)
