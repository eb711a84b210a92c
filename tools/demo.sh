#!/usr/bin/env bash
# `make demo`: grid SimpleNeRF (configs/grid/demo.yaml) and its DS-NeRF baseline (configs/grid/demo_dsnerf.yaml) on
# the built-in synthetic "objects" scene, trained side by side on one core each, then tested (metrics + renders),
# SimpleNeRF's spiral video, both runs' metrics side by side and one held-out frame as a picture. Each step prints its
# wall time (this script is also the demo's timing benchmark, docs/results.md).
#
#   tools/demo.sh                      # what `make demo` runs (after setting up .venv)
#   RUNS=/tmp/r tools/demo.sh          # run folders elsewhere (default runs/)
#
# PYTHON (default .venv/bin/python) and EXTRA (more CLI overrides for both fits and tests, e.g.
# "--trainer.max_steps 20") can be set. The DS-NeRF baseline's output goes to $RUNS/grid_demo_dsnerf.log.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
RUNS=${RUNS:-runs}
mkdir -p "$RUNS"

timed() {  # timed LABEL COMMAND...: runs COMMAND, then prints its wall seconds
  local label=$1 t0=$SECONDS; shift
  "$@"
  echo "[demo] $label: $((SECONDS - t0)) s"
}

train_and_test() {  # train_and_test VARIANT: fit and test configs/grid/VARIANT.yaml into $RUNS/grid_VARIANT
  local run=$RUNS/grid_$1
  # shellcheck disable=SC2086
  local args=(--config "configs/grid/$1.yaml" --trainer.default_root_dir "$run"
              --trainer.logger.init_args.save_dir "$run" ${EXTRA:-})
  timed "fit $1" "$PYTHON" -m simplenerf fit "${args[@]}" --overwrite true
  timed "test $1" "$PYTHON" -m simplenerf test "${args[@]}" --ckpt_path last
}

start=$SECONDS
# The scene is generated on first use: here, once, before the two fits that read it (the folder the configs' data
# module names: simplenerf.data.synthetic).
"$PYTHON" -m simplenerf synthetic data/synthetic/objects_seed0_96x128_20 --kind objects >/dev/null
# Two processes of one thread each use the two cores better than one of two threads after the other (a small batch
# scales poorly across threads); the scores are the same either way.
baseline_log=$RUNS/grid_demo_dsnerf.log
OMP_NUM_THREADS=1 train_and_test demo_dsnerf >"$baseline_log" 2>&1 &
baseline=$!
stop_baseline() {  # its python first (a SIGTERM stops it at a step's end, checkpoint saved), then its subshell
  pkill -TERM -P "$baseline" 2>/dev/null || true
  kill "$baseline" 2>/dev/null || true
}
# Ctrl-C, a kill or a failure here stops the baseline too.
trap stop_baseline EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
echo "[demo] DS-NeRF trains alongside; its output: $baseline_log"
OMP_NUM_THREADS=1 train_and_test demo
baseline_status=0
wait "$baseline" || baseline_status=$?
trap - EXIT  # it has ended: nothing to stop (and its PID may be reused)
if [ "$baseline_status" -ne 0 ]; then
  tail -n 30 "$baseline_log" >&2
  echo "[demo] the DS-NeRF baseline failed; its output: $baseline_log" >&2
  exit 1
fi
grep '^\[demo\]' "$baseline_log"
timed "video" "$PYTHON" -m simplenerf render-video --config configs/grid/demo.yaml \
  --ckpt_path "$RUNS/grid_demo/checkpoints/last.ckpt" --frames 40 --rotations 1 --fps 15 \
  --trainer.default_root_dir "$RUNS/grid_demo"
echo "[demo] total: $((SECONDS - start)) s"
echo "Test metrics on the synthetic 'objects' scene (3 views, same budget), renders in $RUNS/grid_demo*/test:"
"$PYTHON" -m simplenerf results SimpleNeRF="$RUNS/grid_demo" DS-NeRF="$RUNS/grid_demo_dsnerf" --scores both --depth
"$PYTHON" -m benchmarks.quality.demo_picture "$RUNS/grid_demo" "$RUNS/grid_demo_dsnerf" --out docs/images/demo.png
echo "SimpleNeRF's spiral video ([RGB | depth]): $RUNS/grid_demo/video_spiral.mp4"
echo "One held-out frame of both models (photo | render | depths | exact depth): docs/images/demo.png"
