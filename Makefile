# The two commands of the README. Each creates .venv if missing, installs, then runs.
#   make demo   trains SimpleNeRF and DS-NeRF on the built-in synthetic scene, tests both (metrics + renders), video
#   make test   runs the test suite
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SHARED ?= $(abspath ../shared)
# LPIPS needs ImageNet AlexNet weights; the project's shared data has them (else: torch hub cache or a download).
LPIPS_NPZ := $(SHARED)/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
export SIMPLENERF_LPIPS_WEIGHTS ?= $(if $(wildcard $(LPIPS_NPZ)),$(LPIPS_NPZ),)
export SIMPLENERF_SHARED ?= $(SHARED)

.PHONY: setup demo test

# VENV_FLAGS=--system-site-packages: the venv sees PYTHON's packages, so a CUDA torch installed there is kept.
VENV_FLAGS ?=
# The tested torch; tools/install_torch.sh keeps an installed torch that satisfies pyproject.toml.
TORCH_PIN ?= 2.13.0

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV_FLAGS) $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first (README "Install"): kept if the venv already has one that satisfies pyproject.toml; else the
	# pinned CUDA build where nvidia-smi lists a GPU, the CPU build (PyTorch's CPU index) where not. An unpinned
	# resolve would pull the CUDA build everywhere.
	TORCH_PIN=$(TORCH_PIN) bash tools/install_torch.sh $(PY)
	# OpenCV pinned: it draws the demo scene's pictures, and its anti-aliased drawing changes between versions (so
	# would the demo's scores).
	$(PY) -m pip install -q opencv-contrib-python-headless==5.1.0.95
	$(PY) -m pip install -q -e '.[dev]'
	# lpips only for its v0.1 linear heads; --no-deps because it requires torchvision.
	$(PY) -m pip install -q --no-deps lpips==0.1.4
	touch $@

setup: $(VENV)/.installed

# The demo (tools/demo.sh): grid (K-Planes) SimpleNeRF and its DS-NeRF baseline on the built-in "objects" scene
# (configs/grid/), trained side by side, tested, SimpleNeRF's video, the metrics and one picture.
demo: $(VENV)/.installed
	PYTHON=$(PY) bash tools/demo.sh

# Two pytest-xdist workers: the suite is mostly CLI subprocesses and small trainings, which fill two cores better
# side by side (docs/testing.md). TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2

test: $(VENV)/.installed
	$(PY) -m pytest -q -n $(TEST_WORKERS)
