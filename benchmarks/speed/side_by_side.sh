#!/usr/bin/env bash
# The authors' release and ours, alternating in one sitting, on LLFF fern images_4 with 2 views; then one table.
#
#   benchmarks/speed/side_by_side.sh [VARIANT [PRECISIONS [REPS]]]   e.g.  benchmarks/speed/side_by_side.sh B 32-true,bf16-mixed 3
#
# VARIANT (as ../shared/tools/official_timing/README.md):
#   A  the paper's config: 2048 + 2048 rays          release: driver.py --variant A;  ours: configs/llff.yaml
#   B  256 + 256 rays (default)                       release: driver.py --variant B;  ours: configs/llff.yaml
#   C  256 + 256 rays, no augmentations (DS-NeRF-like) release: driver.py --variant C;  ours: configs/dsnerf.yaml
# PRECISIONS are ours, comma-separated (32-true, bf16-mixed, ...); the release always runs fp32. Every rep runs the
# release then ours in each precision, or the reverse order on even reps, so drift of the machine falls on all.
# Each run: WARMUP untimed + STEPS timed iterations (the release's --discard WARMUP). Our loss weights are the configured ones (no warm-up schedule), so
# L_ap, L_av and L_cfc are computed as the release computes them (at weight 0 before its step 10k).
#
# Environment (defaults in brackets):
#   OFFICIAL   [/work/official] holds simplenerf_official/src (the release at c429746), venv/ (its Python) and
#              official_run/ (the layout of build_layout.py); see benchmarks/README.md to set it up
#   HARNESS    [../shared/tools/official_timing]    PYTHON [.venv/bin/python]    SCENE [../shared/data/nerf_llff_data/fern]
#   STEPS [4]  WARMUP [2]  THREADS [2] (OMP_NUM_THREADS of both)  OUT [runs/side_by_side/<variant>_<precision>_<time>]
#   EXTRA      more CLI overrides for ours (e.g. "--model.chunk 4096")
# Results: OUT/release_<V>_<rep>.json (driver.py --json_out; log beside it), OUT/ours_<V>_<P>_<rep>.json (one JSON line
# of `simplenerf benchmark`; log beside it), OUT/table.md (benchmarks/speed/summarize.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
VARIANT=${1:-B} PRECISIONS=${2:-32-true} REPS=${3:-3}
OFFICIAL=${OFFICIAL:-/work/official}
HARNESS=${HARNESS:-../shared/tools/official_timing}
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
STEPS=${STEPS:-4} WARMUP=${WARMUP:-2} THREADS=${THREADS:-2}
OUT=${OUT:-runs/side_by_side/${VARIANT}_${PRECISIONS//,/_}_$(date -u +%Y%m%dT%H%M%SZ)}

case $VARIANT in
  A) config=configs/llff.yaml rays=2048 ;;
  B) config=configs/llff.yaml rays=256 ;;
  C) config=configs/dsnerf.yaml rays=256 ;;
  *) echo "side_by_side.sh: unknown variant $VARIANT (A, B or C)" >&2; exit 2 ;;
esac
if [ "$VARIANT" = A ] && [ $((STEPS + WARMUP)) -gt 9 ]; then
  echo "side_by_side.sh: the release's sparse-depth pool gives 9 full 2048-ray batches: use STEPS + WARMUP <= 9" >&2
  exit 2
fi
for path in "$OFFICIAL/venv/bin/python" "$OFFICIAL/simplenerf_official/src/Trainer01.py" \
            "$OFFICIAL/official_run/data" "$HARNESS/driver.py" "$SCENE/poses_bounds.npy"; do
  [ -e "$path" ] || { echo "side_by_side.sh: missing $path (see benchmarks/README.md)" >&2; exit 2; }
done
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
export OMP_NUM_THREADS=$THREADS WANDB_MODE=offline

ours_args=(--config "$config" -- --data.init_args.scene_dir "$SCENE" --data.init_args.n_views 2
           --data.init_args.factor 4 --data.init_args.rays_per_batch "$rays"
           --data.init_args.sparse_rays_per_batch "$rays" ${EXTRA:-})

# SfM for our sparse depth runs once, untimed, before the sitting (it is cached), so no run's peak RSS includes it.
"$PYTHON" -m simplenerf sparse-depth --config "$config" --data.init_args.scene_dir "$SCENE" \
  --data.init_args.n_views 2 --data.init_args.factor 4 > "$OUT/sparse_depth.log" 2>&1

release() {
  ( cd "$HARNESS" && "$OFFICIAL/venv/bin/python" driver.py --variant "$VARIANT" --iters $((WARMUP + STEPS)) \
      --discard "$WARMUP" --threads "$THREADS" --official_src "$OFFICIAL/simplenerf_official/src" \
      --run_root "$OFFICIAL/official_run" --json_out "$OUT/release_${VARIANT}_$1.json" ) \
    > "$OUT/release_${VARIANT}_$1.log" 2>&1
  echo "release rep $1: $(grep -o '"s_per_iter_median": [0-9.]*' "$OUT/release_${VARIANT}_$1.log")"
}
ours() {  # rep precision
  "$PYTHON" -m simplenerf benchmark --label "$VARIANT" --precision "$2" --steps "$STEPS" --warmup "$WARMUP" \
    "${ours_args[@]}" > "$OUT/ours_${VARIANT}_$2_$1.json" 2> "$OUT/ours_${VARIANT}_$2_$1.log"
  echo "ours $2 rep $1: $(grep -o '"s_per_it": [0-9.]*' "$OUT/ours_${VARIANT}_$2_$1.json")"
}

IFS=, read -r -a precisions <<< "$PRECISIONS"
echo "side by side: variant $VARIANT ($rays + $rays rays), ours in ${precisions[*]}, $REPS reps of $WARMUP +" \
     "$STEPS iterations, $THREADS threads; results in $OUT"
for rep in $(seq 1 "$REPS"); do
  if [ $((rep % 2)) -eq 1 ]; then
    release "$rep"; for p in "${precisions[@]}"; do ours "$rep" "$p"; done
  else
    for ((i = ${#precisions[@]} - 1; i >= 0; i--)); do ours "$rep" "${precisions[i]}"; done; release "$rep"
  fi
done
"$PYTHON" -m benchmarks.speed.summarize "$OUT"/release_*.json "$OUT"/ours_*.json | tee "$OUT/table.md"
