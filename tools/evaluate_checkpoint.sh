#!/usr/bin/env bash
# Test metrics and held-out SfM depth error of one checkpoint of a run of tools/benchmark_fern_cpu.sh, into its own
# folder, so that runs can be compared at an intermediate step as well:
#   tools/evaluate_checkpoint.sh bidirectional 2000     # -> runs/cpu/step002000/fern_bidirectional/{test,heldout_depth.json}
# Then: python tools/compare_runs.py bidirectional=runs/cpu/step002000/fern_bidirectional ...
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
RUNS=${RUNS:-runs/cpu}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$LPIPS_NPZ}
variant=$1 step=$(printf "%06d" "$2")
case $variant in
  bidirectional|one_way) config=configs/cpu/fern_simplenerf.yaml; extra=(--model.supervision "$variant") ;;
  dsnerf) config=configs/cpu/fern_dsnerf.yaml; extra=() ;;
  *) echo "unknown variant $variant (bidirectional, one_way, dsnerf)" >&2; exit 2 ;;
esac
ckpt=$RUNS/fern_$variant/checkpoints/step$step.ckpt
out=$RUNS/step$step/fern_$variant
mkdir -p "$out"
args=(--config "$config" "${extra[@]}" --data.init_args.scene_dir "$SCENE")
"$PYTHON" -m simplenerf test "${args[@]}" --trainer.logger false --trainer.default_root_dir "$out" \
  --evaluation.output_dir "$out/test" --ckpt_path "$ckpt"
"$PYTHON" tools/heldout_depth_error.py --config "$config" --ckpt "$ckpt" --out "$out/heldout_depth.json" -- \
  "${args[@]:2}"
