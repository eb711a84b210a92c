#!/usr/bin/env bash
# The CPU quality benchmark: SimpleNeRF (bidirectional and one_way supervision) vs the DS-NeRF baseline on LLFF fern,
# images_8, 2 views, small networks, the same 5000-iteration budget (configs/cpu/*.yaml, about 30 minutes per
# SimpleNeRF run on a 2-core CPU). For each run: fit, test (PSNR / SSIM / LPIPS on the 3 test frames) and the depth
# error at held-out SfM points (tools/heldout_depth_error.py); then one table of all runs.
#
#   tools/benchmark_fern_cpu.sh                       # all three, one after another
#   tools/benchmark_fern_cpu.sh one_way               # one of: bidirectional one_way dsnerf
#   OMP_NUM_THREADS=1 tools/benchmark_fern_cpu.sh dsnerf & OMP_NUM_THREADS=1 tools/benchmark_fern_cpu.sh one_way &
#
# SCENE (default ../shared/data/nerf_llff_data/fern), PYTHON (default .venv/bin/python), RUNS (default runs/cpu) and
# EXTRA (more CLI overrides, e.g. EXTRA="--trainer.max_steps 10" for a smoke test) can be set.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
RUNS=${RUNS:-runs/cpu}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$LPIPS_NPZ}

args_of() {  # config arguments of a variant
  case $1 in
    bidirectional) echo "--config configs/cpu/fern_simplenerf.yaml --model.supervision bidirectional" ;;
    one_way) echo "--config configs/cpu/fern_simplenerf.yaml --model.supervision one_way" ;;
    dsnerf) echo "--config configs/cpu/fern_dsnerf.yaml" ;;
    *) echo "unknown variant $1 (bidirectional, one_way, dsnerf)" >&2; exit 2 ;;
  esac
}

variants=("$@")
[ ${#variants[@]} -gt 0 ] || variants=(bidirectional one_way dsnerf)
for variant in "${variants[@]}"; do
  run=$RUNS/fern_$variant
  # shellcheck disable=SC2046
  set -- $(args_of "$variant") --data.init_args.scene_dir "$SCENE" ${EXTRA:-}
  config=$2 model_args=("${@:3}")
  set -- "$@" --trainer.default_root_dir "$run" --trainer.logger.init_args.save_dir "$run"
  start=$(date +%s)
  "$PYTHON" -m simplenerf fit "$@"
  echo "$variant: fit took $(( $(date +%s) - start )) s" | tee "$run/fit_time.txt"
  "$PYTHON" -m simplenerf test "$@" --ckpt_path last
  "$PYTHON" tools/heldout_depth_error.py --config "$config" --ckpt "$run/checkpoints/last.ckpt" \
    --out "$run/heldout_depth.json" -- "${model_args[@]}"
done

table=()
for variant in bidirectional one_way dsnerf; do
  [ -f "$RUNS/fern_$variant/test/summary.json" ] && table+=("$variant=$RUNS/fern_$variant")
done
"$PYTHON" tools/compare_runs.py "${table[@]}"
