#!/usr/bin/env bash
# What flushing subnormal floats to zero (simplenerf.run.hardware.flush_denormals, on by default) is worth: the same
# training step timed from a checkpoint's weights with SIMPLENERF_DENORMALS=keep (the CPU's default) and without,
# alternating in one sitting, so that drift of the machine falls on both.
#
#   benchmarks/speed/denormals.sh CONFIG CKPT [REPS] [-- OVERRIDES...]
#   e.g. benchmarks/speed/denormals.sh configs/grid/simplerf_images4.yaml RUN/checkpoints/step001200.ckpt 3 -- \
#            --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern \
#            --model.objective.color_spread_weight 1.0 --model.objective.distortion_weight 0.03
#
# CKPT is a checkpoint of a fit of CONFIG: a fit's densities reach subnormal values only once it has learnt empty
# space, so a fresh initialisation shows no difference. `simplenerf benchmark` applies every loss at its configured
# weight (no warm-up schedule): pass the weights the fit had at CKPT's step as OVERRIDES.
# Environment: PYTHON [.venv/bin/python]  STEPS [8]  WARMUP [2]  THREADS [2] (OMP_NUM_THREADS)
#              OUT [runs/denormals/<time>]
# Results: OUT/<keep|flush>_<rep>.json (one JSON line of `simplenerf benchmark` each; its log beside it), then one
# line per mode: median s/it over the reps' medians, and flush's speed-up.
set -euo pipefail
cd "$(dirname "$0")/../.."
[ $# -ge 2 ] || { sed -n 2,9p "$0" >&2; exit 2; }
CONFIG=$1 CKPT=$2; shift 2
REPS=3
if [ $# -gt 0 ] && [ "$1" != -- ]; then REPS=$1; shift; fi
[ $# -gt 0 ] && [ "$1" = -- ] && shift
PYTHON=${PYTHON:-.venv/bin/python} STEPS=${STEPS:-8} WARMUP=${WARMUP:-2} THREADS=${THREADS:-2}
OUT=${OUT:-runs/denormals/$(date -u +%Y%m%dT%H%M%SZ)}
for path in "$CONFIG" "$CKPT"; do [ -f "$path" ] || { echo "denormals.sh: no file $path" >&2; exit 2; }; done
mkdir -p "$OUT"
export OMP_NUM_THREADS=$THREADS WANDB_MODE=offline

one() {  # mode rep
  local mode=$1 rep=$2 env=(); shift 2
  [ "$mode" = keep ] && env=(SIMPLENERF_DENORMALS=keep)
  env "${env[@]}" "$PYTHON" -m simplenerf benchmark --config "$CONFIG" --weights "$CKPT" --steps "$STEPS" \
    --warmup "$WARMUP" --label "$mode" -- "$@" > "$OUT/${mode}_$rep.json" 2> "$OUT/${mode}_$rep.log"
  echo "rep $rep $mode: $("$PYTHON" -c 'import json,sys; print(round(json.loads(open(sys.argv[1]).read().splitlines()[-1])["s_per_it"], 3))' "$OUT/${mode}_$rep.json") s/it"
}
for rep in $(seq 1 "$REPS"); do
  if [ $((rep % 2)) = 1 ]; then one keep "$rep" "$@"; one flush "$rep" "$@"; else one flush "$rep" "$@"; one keep "$rep" "$@"; fi
done
"$PYTHON" - "$OUT" <<'PY'
import json, statistics, sys
from pathlib import Path
s = {m: statistics.median(json.loads(p.read_text().splitlines()[-1])["s_per_it"] for p in Path(sys.argv[1]).glob(f"{m}_*.json"))
     for m in ("keep", "flush")}
print(f"median s/it: keep {s['keep']:.3f}, flush {s['flush']:.3f}; flush {s['keep'] / s['flush']:.2f}x as fast")
PY
