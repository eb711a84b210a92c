# The two commands of the README. Each creates .venv if missing, installs, then runs.
#   make demo   trains SimpleNeRF and DS-NeRF on the built-in synthetic scene, tests both (metrics + renders), video
#   make test   runs the test suite
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SIMPLENERF := $(VENV)/bin/simplenerf
SHARED ?= $(abspath ../shared)
# LPIPS needs ImageNet AlexNet weights; the project's shared data has them (else: torch hub cache or a download).
LPIPS_NPZ := $(SHARED)/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
export SIMPLENERF_LPIPS_WEIGHTS ?= $(if $(wildcard $(LPIPS_NPZ)),$(LPIPS_NPZ),)
export SIMPLENERF_SHARED ?= $(SHARED)

.PHONY: setup demo test

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first and pinned: the CPU wheel; an unpinned resolve would pull CUDA packages.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	# lpips only for its v0.1 linear heads; --no-deps because it requires torchvision.
	$(PY) -m pip install -q --no-deps lpips==0.1.4
	touch $@

setup: $(VENV)/.installed

# The demo: grid (K-Planes) SimpleNeRF and its DS-NeRF baseline on the built-in "objects" scene (configs/grid/).
DEMO := --config configs/grid/demo.yaml
DSNERF := --config configs/grid/demo_dsnerf.yaml

demo: $(VENV)/.installed
	$(SIMPLENERF) fit $(DEMO) --overwrite true
	$(SIMPLENERF) test $(DEMO) --ckpt_path last
	$(SIMPLENERF) fit $(DSNERF) --overwrite true
	$(SIMPLENERF) test $(DSNERF) --ckpt_path last
	$(SIMPLENERF) render-video $(DEMO) --ckpt runs/grid_demo/checkpoints/last.ckpt --scale 1.5 --frames 40 --rotations 1 --fps 15
	@echo "Test metrics on the synthetic 'objects' scene (3 views, same budget), renders in runs/grid_demo*/test:"
	@$(SIMPLENERF) results SimpleNeRF=runs/grid_demo DS-NeRF=runs/grid_demo_dsnerf --scores both --depth
	@$(PY) -m benchmarks.demo_picture runs/grid_demo runs/grid_demo_dsnerf --out docs/images/demo.png
	@echo "SimpleNeRF's spiral video ([RGB | depth]): runs/grid_demo/video_spiral.mp4"
	@echo "One held-out frame of both models (photo | render | depths | exact depth): docs/images/demo.png"

test: $(VENV)/.installed
	$(PY) -m pytest -q
