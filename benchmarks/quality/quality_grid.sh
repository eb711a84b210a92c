#!/usr/bin/env bash
# Grid SimpleNeRF vs grid DS-NeRF (configs/grid/*.yaml), 2 views, over scenes and seeds: for each run fit, test
# (full-frame and masked PSNR / SSIM / LPIPS) and, on LLFF scenes, the depth error at held-out SfM points
# (`simplenerf heldout-depth`); then a table per scene of mean ± std over the seeds per model (`simplenerf results`).
#
#   benchmarks/quality/quality_grid.sh fern                          # the configs' budget (3000 steps), seed 0, both models
#   SEEDS="0 1 2" STEPS=400 benchmarks/quality/quality_grid.sh fern horns realestate
#   VARIANTS=dsnerf OMP_NUM_THREADS=1 SEEDS="0 1 2" STEPS=400 benchmarks/quality/quality_grid.sh fern &   # two streams on
#   VARIANTS=simplenerf OMP_NUM_THREADS=1 SEEDS="0 1 2" STEPS=400 benchmarks/quality/quality_grid.sh fern & # a 2-core CPU
#   TABLE_ONLY=1 SEEDS="0 1 2" benchmarks/quality/quality_grid.sh fern horns realestate   # only the table of finished runs
#
# A scene is fern, horns (../shared/data/nerf_llff_data/<name>, images_8), realestate (the RealEstate-10K clip in
# ../shared/data/realestate10k, 256x256) or the path of a scene folder: an LLFF scene (poses_bounds.npy) or a
# RealEstate-10K clip (<id>.txt + frames/). STEPS shortens the budget: the learning rate still decays to a tenth by the
# last step and the warm-up stays 10% of it. Runs: $RUNS/<scene>_seed<S>_<variant> (RUNS default runs/grid).
# PYTHON (default .venv/bin/python), EXTRA (more CLI overrides for every fit) and, with STEPS, DEPTH_WEIGHT (the
# weight of L_ap, L_av and L_cfc after the warm-up; default 0.1, the paper's) can be set. A variant is a config of
# configs/grid/ (simplenerf, dsnerf, simplerf: Simple-RF's augmentation); with STEPS, a config's mass-concentration
# losses (<name>_concentration) get CONCENTRATION_WEIGHT (default 0.01) from 20% of the steps. RESUME=1 continues a
# stopped fit from its last checkpoint instead of starting it over (the fit's own time is then the resumed part's).
set -euo pipefail
cd "$(dirname "$0")/../.."
PYTHON=${PYTHON:-.venv/bin/python}
RUNS=${RUNS:-runs/grid}
SEEDS=${SEEDS:-0}
VARIANTS=${VARIANTS:-simplenerf dsnerf}
SHARED=${SHARED:-../shared/data}
export WANDB_MODE=${WANDB_MODE:-offline}
LPIPS_NPZ=$SHARED/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
[ -f "$LPIPS_NPZ" ] && export SIMPLENERF_LPIPS_WEIGHTS=${SIMPLENERF_LPIPS_WEIGHTS:-$(realpath "$LPIPS_NPZ")}
[ $# -gt 0 ] || { sed -n '2,18p' "$0"; exit 2; }

scene_dir() {  # scene name or path -> folder
  case $1 in
    fern|horns) echo "$SHARED/nerf_llff_data/$1" ;;
    realestate) ls -d "$SHARED"/realestate10k/*/ | head -1 ;;
    *) echo "$1" ;;
  esac
}

budget=()
if [ -n "${STEPS:-}" ]; then
  warm=$(( STEPS / 10 )) late=$(( STEPS / 5 ))
  budget=(--trainer.max_steps "$STEPS" --model.lr_scheduler.init_args.decay_steps "$STEPS"
          --trainer.val_check_interval "$STEPS" --checkpoint.every_n_train_steps "$STEPS")
  w=${DEPTH_WEIGHT:-0.1}
  sched="{points: [[0, 0.0], [$warm, $w]], views: [[0, 0.0], [$warm, $w]], cfc: [[0, 0.0], [$warm, $w]]}"
fi

table=()
for scene in "$@"; do
  dir=$(scene_dir "$scene")
  [ -d "$dir" ] || { echo "scene folder $dir not found (scene '$scene')" >&2; exit 2; }
  name=$(basename "$dir")
  if [ -f "$dir/poses_bounds.npy" ]; then prefix=""; llff=1; else prefix=realestate_; llff=0; fi
  for seed in $SEEDS; do
    for variant in $VARIANTS; do
      run=$RUNS/${name}_seed${seed}_$variant
      table+=("$variant=$run")
      [ -n "${TABLE_ONLY:-}" ] && continue
      config=configs/grid/$prefix$variant.yaml
      args=(--data.init_args.scene_dir "$dir" --seed_everything "$seed" --data.init_args.seed "$seed" "${budget[@]}")
      if [ -n "${STEPS:-}" ] && [ "${variant%dsnerf}" = "$variant" ]; then  # a variant with the warm-up
        schedules=$sched
        for loss in $(grep -o '^ *[a-z_]*_concentration:' "$config" | tr -d ' :' | sort -u); do
          schedules="${schedules%\}}, $loss: [[0, 0.0], [$late, ${CONCENTRATION_WEIGHT:-0.01}]]}"
        done
        args+=(--trainer.callbacks.init_args.schedules "$schedules")
      fi
      # shellcheck disable=SC2206
      args+=(${EXTRA:-})
      start=$(date +%s) resume=(--overwrite true)
      if [ -n "${RESUME:-}" ] && [ -f "$run/checkpoints/last.ckpt" ]; then resume=(--ckpt_path last); fi
      "$PYTHON" -m simplenerf fit --config "$config" "${args[@]}" --trainer.default_root_dir "$run" \
        --trainer.logger.init_args.save_dir "$run" "${resume[@]}"
      echo "$name $variant seed $seed: fit took $(( $(date +%s) - start )) s" | tee "$run/fit_time.txt"
      "$PYTHON" -m simplenerf test --config "$config" "${args[@]}" --trainer.logger false \
        --trainer.default_root_dir "$run" --ckpt_path "$run/checkpoints/last.ckpt"
      if [ $llff = 1 ]; then
        "$PYTHON" -m simplenerf heldout-depth --config "$config" --ckpt "$run/checkpoints/last.ckpt" \
          --out "$run/heldout_depth.json" -- "${args[@]}"
      fi
    done
  done
done

done_runs=()
for entry in "${table[@]}"; do [ -f "${entry#*=}/test/summary.json" ] && done_runs+=("$entry"); done
[ ${#done_runs[@]} -gt 0 ] && "$PYTHON" -m simplenerf results --per-scene --scores full --depth "${done_runs[@]}"
