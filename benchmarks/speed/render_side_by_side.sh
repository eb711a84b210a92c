#!/usr/bin/env bash
# Full-frame rendering, the authors' release and ours, of fern's first test view (frame 0, 1008x756 = 762048 rays,
# images_4, 2-view split; initial weights on both sides: the same work per ray), one after the other; then rays/s.
#
#   benchmarks/speed/render_side_by_side.sh [ROWS]
#
# ROWS renders only the top ROWS rows on both sides (1008 rays each): a full frame on a 2-core CPU takes hours for
# either (about 195 M field evaluations of the 8x256 MLP), so on a CPU use e.g. ROWS=32. Both sides render in fp32
# with their own chunking (release: 4096 rays per chunk, 16384 points per MLP call; ours: --model.chunk, 8192 in
# configs/llff.yaml). The release's side needs a training folder written by driver.py (its configs; any variant
# with the augmentations: the default train9002 is variant B's, made by side_by_side.sh B or driver.py --variant B).
#
# Environment as benchmarks/speed/side_by_side.sh: OFFICIAL [/work/official], PYTHON [.venv/bin/python],
# SCENE [../shared/data/nerf_llff_data/fern], THREADS [2], OUT [runs/render_side_by_side/<time>], TRAIN_NUM [9002],
# PRECISION [32-true] (ours), EXTRA (more overrides for ours), DEVICE [cpu] (cuda: the release on the GPU too).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROWS=${1:-}
OFFICIAL=${OFFICIAL:-/work/official}
PYTHON=${PYTHON:-.venv/bin/python}
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
THREADS=${THREADS:-2} TRAIN_NUM=${TRAIN_NUM:-9002} PRECISION=${PRECISION:-32-true} DEVICE=${DEVICE:-cpu}
OUT=${OUT:-runs/render_side_by_side/$(date -u +%Y%m%dT%H%M%SZ)}
train_dir=$(printf "%s/official_run/runs/training/train%04d" "$OFFICIAL" "$TRAIN_NUM")
[ -f "$train_dir/fern/ModelConfigs.json" ] || {
  echo "render_side_by_side.sh: $train_dir has no fern/ModelConfigs.json: run the release's driver.py first" \
       "(benchmarks/README.md)" >&2; exit 2; }
mkdir -p "$OUT"
export OMP_NUM_THREADS=$THREADS WANDB_MODE=offline
rows=()
[ -z "$ROWS" ] || rows=(--rows "$ROWS")

"$OFFICIAL/venv/bin/python" benchmarks/speed/release_render.py --official_src "$OFFICIAL/simplenerf_official/src" \
  --run_root "$OFFICIAL/official_run" --train_num "$TRAIN_NUM" --frame 0 --frames 1 --threads "$THREADS" \
  --device "$DEVICE" "${rows[@]}" > "$OUT/release_render.json" 2> "$OUT/release_render.log"
"$PYTHON" -m benchmarks.speed.render --config configs/llff.yaml --frames 1 --precision "$PRECISION" "${rows[@]}" \
  -- --data.init_args.scene_dir "$SCENE" --data.init_args.n_views 2 --data.init_args.factor 4 ${EXTRA:-} \
  > "$OUT/ours_render.json" 2> "$OUT/ours_render.log"
"$PYTHON" - "$OUT/release_render.json" "$OUT/ours_render.json" <<'EOF'
import json, sys
release, ours = (json.loads(open(p).read().strip().splitlines()[-1]) for p in sys.argv[1:])
print("| | frame | rays | s/frame | CPU s/frame | rays/s | peak RSS GiB |\n|---|---|---|---|---|---|---|")
for name, r in (("release", release), ("ours", ours)):
    shape = "x".join(str(v) for v in r["frame_shape"])
    print(f"| {name} | {shape} | {r['rays_per_frame']:.0f} | {r['s_per_frame']:.1f} | {r['cpu_s_per_frame']:.1f} "
          f"| {r['rays_per_s']:.0f} | {r['peak_rss_gib']:.2f} |")
print(f"\nrays/s ours / release: {ours['rays_per_s'] / release['rays_per_s']:.2f}")
EOF
