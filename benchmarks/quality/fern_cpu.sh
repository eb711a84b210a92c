#!/usr/bin/env bash
# The CPU quality benchmark: SimpleNeRF (bidirectional and one_way supervision) vs the DS-NeRF baseline on LLFF fern,
# images_8, 2 views, small networks, the same 5000-iteration budget (configs/cpu/*.yaml; a bidirectional SimpleNeRF
# run took 68 minutes on the 2-core CPU in 2026-12, partly shared with other jobs). For each run: fit, test (PSNR / SSIM / LPIPS on the 3 test frames) and the
# depth error at held-out SfM points (`simplenerf heldout-depth`); then one table of all runs (`simplenerf results`).
#
#   benchmarks/quality/fern_cpu.sh                       # all three, one after another
#   benchmarks/quality/fern_cpu.sh one_way               # one of: bidirectional one_way dsnerf
#   OMP_NUM_THREADS=1 benchmarks/quality/fern_cpu.sh dsnerf & OMP_NUM_THREADS=1 benchmarks/quality/fern_cpu.sh one_way &
#   benchmarks/quality/fern_cpu.sh --step 2000 bidirectional one_way dsnerf
#       # no training: scores the runs' step-2000 checkpoints into runs/cpu/step002000/fern_<variant>/
#
# SCENE (default ../shared/data/nerf_llff_data/fern), PYTHON (default .venv/bin/python), RUNS (default runs/cpu) and
# EXTRA (more CLI overrides, e.g. EXTRA="--trainer.max_steps 10" for a smoke test) can be set.
set -euo pipefail
cd "$(dirname "$0")/../.."
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
RUNS=${RUNS:-runs/cpu}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$LPIPS_NPZ}

step=""
if [ "${1:-}" = "--step" ]; then step=$(printf "%06d" "$2"); shift 2; fi

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
  if [ -z "$step" ]; then  # train, then score the last checkpoint into the run folder
    out=$run ckpt=$run/checkpoints/last.ckpt
    start=$(date +%s)
    "$PYTHON" -m simplenerf fit "$@" --trainer.default_root_dir "$run" --trainer.logger.init_args.save_dir "$run"
    echo "$variant: fit took $(( $(date +%s) - start )) s" | tee "$run/fit_time.txt"
  else  # score an intermediate checkpoint into its own folder
    out=$RUNS/step$step/fern_$variant ckpt=$run/checkpoints/step$step.ckpt
  fi
  "$PYTHON" -m simplenerf test "$@" --trainer.logger false --trainer.default_root_dir "$out" \
    --evaluation.output_dir "$out/test" --ckpt_path "$ckpt"
  "$PYTHON" -m simplenerf heldout-depth --config "$config" --ckpt "$ckpt" --out "$out/heldout_depth.json" \
    -- "${model_args[@]}"
done

table=()
for variant in bidirectional one_way dsnerf; do
  out=$RUNS/fern_$variant
  [ -z "$step" ] || out=$RUNS/step$step/fern_$variant
  [ -f "$out/test/summary.json" ] && table+=("$variant=$out")
done
"$PYTHON" -m simplenerf results --scores full --depth "${table[@]}"
