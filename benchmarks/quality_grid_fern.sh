#!/usr/bin/env bash
# Grid SimpleNeRF vs grid DS-NeRF on LLFF fern, images_8, 2 views (configs/grid/{simplenerf,dsnerf}.yaml): for each,
# fit, test (PSNR / SSIM / LPIPS on the 3 test frames; no dense reference depth here, so no depth-map scores) and the
# depth error at held-out SfM points (tools/heldout_depth_error.py, as tools/benchmark_fern_cpu.sh), then one table.
#
#   benchmarks/quality_grid_fern.sh                    # both, the configs' 3000 steps
#   STEPS=1500 benchmarks/quality_grid_fern.sh dsnerf  # one of: simplenerf dsnerf; a shorter budget (the learning
#                                                      # rate still decays to a tenth, the warm-up stays 10%)
#   SEED=1 benchmarks/quality_grid_fern.sh             # another seed (runs/grid/fern_seed1_*)
#
# SCENE (default ../shared/data/nerf_llff_data/fern), PYTHON (default .venv/bin/python), RUNS (default runs/grid) and
# EXTRA (more CLI overrides) can be set.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
RUNS=${RUNS:-runs/grid}
SEED=${SEED:-0}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=../shared/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$LPIPS_NPZ}

budget=()
if [ -n "${STEPS:-}" ]; then
  warm=$(( STEPS / 10 ))
  budget=(--trainer.max_steps "$STEPS" --model.lr_scheduler.init_args.decay_steps "$STEPS"
          --trainer.val_check_interval "$STEPS" --checkpoint.every_n_train_steps "$(( STEPS / 2 ))")
  sched="{points: [[0, 0.0], [$warm, 0.1]], views: [[0, 0.0], [$warm, 0.1]], cfc: [[0, 0.0], [$warm, 0.1]]}"
fi

variants=("$@")
[ ${#variants[@]} -gt 0 ] || variants=(simplenerf dsnerf)
for variant in "${variants[@]}"; do
  run=$RUNS/fern_seed${SEED}_$variant
  config=configs/grid/$variant.yaml
  args=(--data.init_args.scene_dir "$SCENE" --seed_everything "$SEED" --data.init_args.seed "$SEED" "${budget[@]}")
  if [ -n "${STEPS:-}" ] && [ "$variant" = simplenerf ]; then
    args+=(--trainer.callbacks.init_args.schedules "$sched")
  fi
  # shellcheck disable=SC2206
  args+=(${EXTRA:-})
  start=$(date +%s)
  "$PYTHON" -m simplenerf fit --config "$config" "${args[@]}" --trainer.default_root_dir "$run" \
    --trainer.logger.init_args.save_dir "$run"
  echo "$variant: fit took $(( $(date +%s) - start )) s" | tee "$run/fit_time.txt"
  "$PYTHON" -m simplenerf test --config "$config" "${args[@]}" --trainer.logger false \
    --trainer.default_root_dir "$run" --ckpt_path "$run/checkpoints/last.ckpt"
  "$PYTHON" tools/heldout_depth_error.py --config "$config" --ckpt "$run/checkpoints/last.ckpt" \
    --out "$run/heldout_depth.json" -- "${args[@]}"
done

table=()
for variant in simplenerf dsnerf; do
  run=$RUNS/fern_seed${SEED}_$variant
  [ -f "$run/test/summary.json" ] && table+=("grid-$variant=$run")
done
"$PYTHON" tools/compare_runs.py "${table[@]}"
