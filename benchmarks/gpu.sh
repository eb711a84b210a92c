#!/usr/bin/env bash
# GPU speed of the paper's config, in under 8 minutes on one GPU: configs/llff.yaml on LLFF fern (images_4, 2 views),
# 2048 + 2048 rays per iteration, all losses on (no warm-up schedule): s/it, rays/s, field evaluations/s and peak GPU
# memory in fp32, fp32 + TF32 matrix products, and bf16-mixed; then full-frame rendering rays/s of the first test view
# (1008x756) in fp32 and TF32. Prints the GPU's name first and a markdown table last; JSON lines in OUT.
#
#   benchmarks/gpu.sh
#
# Without CUDA it prints "gpu.sh: SKIPPED ..." and exits 0, measuring nothing.
# Environment (defaults in brackets): PYTHON [.venv/bin/python if present, else python3], SCENE
# [../shared/data/nerf_llff_data/fern; on a machine without ../shared copy the scene into the checkout], OUT
# [runs/gpu], STEPS [20], WARMUP [5], FRAMES [2] (timed, after one warm-up frame), WHEELS [.whl] (if that folder holds
# wheels, they are installed into /tmp/site first: the project's dependencies that the GPU machine's image lacks).
# Each run has a time limit so that the whole script stays under 8 minutes (SfM 90 s, each training run 90 s, each
# render 60 s); a run that hits its limit is reported and the script goes on.
set -uo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PYTHON:-}" ]; then
  if [ -x .venv/bin/python ]; then PYTHON=.venv/bin/python; else PYTHON=python3; fi
fi
SCENE=${SCENE:-../shared/data/nerf_llff_data/fern}
OUT=${OUT:-runs/gpu}
STEPS=${STEPS:-20} WARMUP=${WARMUP:-5} FRAMES=${FRAMES:-2}
WHEELS=${WHEELS:-.whl}
export WANDB_MODE=offline PYTHONUNBUFFERED=1
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}

if compgen -G "$WHEELS/*.whl" > /dev/null; then
  "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    "$WHEELS"/*.whl && export PYTHONPATH=/tmp/site:$PYTHONPATH
fi
if ! "$PYTHON" -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)' 2> /dev/null; then
  echo "gpu.sh: SKIPPED: no CUDA device (torch.cuda.is_available() is False for $PYTHON); nothing measured" >&2
  exit 0
fi
"$PYTHON" -c 'import torch; p = torch.cuda.get_device_properties(0)
print(f"GPU: {p.name}, {p.total_memory / 2**30:.0f} GiB, {p.multi_processor_count} SMs; torch {torch.__version__},"
      f" CUDA {torch.version.cuda}")'
command -v nvidia-smi > /dev/null && nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader
[ -f "$SCENE/poses_bounds.npy" ] || { echo "gpu.sh: no LLFF scene at $SCENE (set SCENE)" >&2; exit 2; }
mkdir -p "$OUT"
jsonl=$OUT/gpu_$(date -u +%Y%m%dT%H%M%SZ).jsonl
data=(--data.init_args.scene_dir "$SCENE" --data.init_args.n_views 2 --data.init_args.factor 4)
start=$SECONDS

# SfM (pycolmap, on the CPU) once, untimed and cached, so that no timed run includes it.
timeout 90 "$PYTHON" -m simplenerf sparse-depth --config configs/llff.yaml "${data[@]}" > "$OUT/sparse_depth.log" 2>&1 \
  || { echo "gpu.sh: sparse depth (SfM) failed or timed out, see $OUT/sparse_depth.log" >&2; exit 1; }

run() {  # run LIMIT NAME PYTHON_ARGS...: one measuring process; its JSON line is appended to $jsonl
  local limit=$1 name=$2; shift 2
  if timeout "$limit" "$PYTHON" "$@" > "$OUT/$name.json" 2> "$OUT/$name.log"; then
    tail -n 1 "$OUT/$name.json" >> "$jsonl"
    echo "$name done ($((SECONDS - start)) s in)"
  else
    echo "gpu.sh: $name failed or hit its ${limit} s limit, see $OUT/$name.log" >&2
  fi
}
train=(--config configs/llff.yaml --steps "$STEPS" --warmup "$WARMUP")
run 90 train_fp32 -m simplenerf benchmark "${train[@]}" --label fp32 --precision 32-true -- "${data[@]}"
run 90 train_tf32 -m simplenerf benchmark "${train[@]}" --label tf32 --precision 32-true --tf32 -- "${data[@]}"
run 90 train_bf16 -m simplenerf benchmark "${train[@]}" --label bf16 --precision bf16-mixed -- "${data[@]}"
render=(--config configs/llff.yaml --frames "$FRAMES" --warmup 1)
run 60 render_fp32 -m benchmarks.render "${render[@]}" --label fp32 --precision 32-true -- "${data[@]}"
run 60 render_tf32 -m benchmarks.render "${render[@]}" --label tf32 --precision 32-true --tf32 -- "${data[@]}"

echo "total $((SECONDS - start)) s; JSON lines in $jsonl"
[ -s "$jsonl" ] || exit 1
"$PYTHON" - "$jsonl" <<'EOF'
import json, sys
rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
print(f"\n{rows[0]['device']}, torch {rows[0]['torch']}, commit {rows[0]['commit']}")
print("\n| training (2048 + 2048 rays) | s/it median (min-max) | rays/s | M field evals/s | ~matmul TFLOP/s "
      "| peak GPU GiB (reserved) |\n|---|---|---|---|---|---|")
for r in rows:
    if r["benchmark"] == "train_step":
        print(f"| {r['label']} | {r['s_per_it']:.3f} ({r['s_per_it_min']:.3f}-{r['s_per_it_max']:.3f}) "
              f"| {r['rays_per_s']:.0f} | {r['field_evaluations_per_s'] / 1e6:.0f} | {r['approx_matmul_tflops']:.1f} "
              f"| {r['peak_cuda_gib']:.1f} ({r['peak_cuda_reserved_gib']:.1f}) |")
print("\n| rendering (full test view) | frame | s/frame | rays/s | peak GPU GiB |\n|---|---|---|---|---|")
for r in rows:
    if r["benchmark"] == "render":
        shape = "x".join(str(v) for v in r["frame_shape"])
        print(f"| {r['label']} | {shape} | {r['s_per_frame']:.2f} | {r['rays_per_s']:.0f} | {r['peak_cuda_gib']:.1f} |")
EOF
