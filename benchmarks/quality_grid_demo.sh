#!/usr/bin/env bash
# The grid demo, timed: exactly the commands `make demo` runs (docs/results.md "Grid backbone"), each with its wall time and
# the process's CPU time, then the test metrics of both runs side by side.
#
#   benchmarks/quality_grid_demo.sh                 # from a fresh clone: the scene and SfM are computed on first use
#   RUNS=/tmp/r benchmarks/quality_grid_demo.sh     # run folders elsewhere (default runs/)
#
# PYTHON (default .venv/bin/python) and EXTRA (more CLI overrides for both fits, e.g. "--trainer.max_steps 20") can
# be set. The thread count is torch's default (all cores) unless OMP_NUM_THREADS says otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
RUNS=${RUNS:-runs}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$LPIPS_NPZ}

timed() {  # timed LABEL COMMAND...: runs COMMAND, then prints its wall and CPU (user + system) seconds
  local label=$1; shift
  /usr/bin/env time -f "$label: %e s wall, %U + %S s CPU" "$@"
}

start=$(date +%s)
for variant in demo demo_dsnerf; do
  run=$RUNS/grid_$variant
  # shellcheck disable=SC2086
  args=(--config "configs/grid/$variant.yaml" --trainer.default_root_dir "$run"
        --trainer.logger.init_args.save_dir "$run" ${EXTRA:-})
  timed "fit $variant" "$PYTHON" -m simplenerf fit "${args[@]}"
  timed "test $variant" "$PYTHON" -m simplenerf test "${args[@]}" --ckpt_path last
done
timed "video" "$PYTHON" -m simplenerf render-video --config configs/grid/demo.yaml \
  --ckpt "$RUNS/grid_demo/checkpoints/last.ckpt" --scale 1.5 --frames 40 --rotations 1 --fps 15 -- --trainer.default_root_dir "$RUNS/grid_demo"
echo "total: $(( $(date +%s) - start )) s wall"
"$PYTHON" -m simplenerf results SimpleNeRF="$RUNS/grid_demo" DS-NeRF="$RUNS/grid_demo_dsnerf" --scores both --depth
