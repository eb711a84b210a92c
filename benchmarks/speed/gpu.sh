#!/usr/bin/env bash
# The paper's path on one CUDA GPU, in under 10 minutes: configs/llff.yaml on LLFF fern (images_4, 2 views).
#
#   benchmarks/speed/gpu.sh [OUT]            # OUT: the output folder (default runs/gpu/<UTC date and time>)
#   benchmarks/speed/gpu.sh --dry-run [OUT]  # prints each command it would run (with its time limit); runs nothing
#
# Steps, each with a time limit (in brackets; all of them together at most BUDGET = 570 s):
#   1. SfM for the sparse depth (pycolmap, CPU), once, cached, so that no measured process includes it [60 s]
#   2. `simplenerf benchmark`: the paper's training step (2048 + 2048 rays, every loss on), WARMUP + STEPS
#      iterations, in fp32, fp32 with TF32 matrix products and bf16-mixed: s/it and peak GPU memory [55 s each]
#   3. the release-equivalence check (benchmarks/equivalence/check.py) with both sides on the GPU (--device cuda):
#      one training step with 2, 3 and 4 views and a 100-step trajectory, no data rows (they run on the CPU) [110 s]
#   4. a FIT_STEPS-step fit of configs/llff.yaml (default 500) [150 s], with these overrides so that it fits the time:
#      --trainer.precision bf16-mixed, configs/overrides/budget/warmup_10.yaml (L_ap, L_av, L_cfc from step 10, not
#      10000, so that the masked losses run), validation every FIT_STEPS / 2 steps, a checkpoint at the end, W&B offline
#      (where PYTHON cannot import wandb: no logger, `--trainer.logger false`, said in the fit's row)
#   5. `simplenerf test` of that fit (every test view, full frames, the ten metrics) [55 s]
# A step that fails or hits its limit is recorded as such and the script goes on (a fit stopped by its limit still
# writes last.ckpt, which the test then scores). It prints the GPU's model first and a summary last.
#
# Output (OUT): results.jsonl (one JSON line per step: its status, wall seconds and what it measured: the machine;
# `simplenerf benchmark`'s line; the equivalence check's rows; the fit's global step; the test's means), summary.md,
# logs/<step>.log (each step's output), fit/ (the run: checkpoints, config.yaml, test/), release_equivalence.md (the
# table). benchmarks/speed/gpu_report.py writes results.jsonl and summary.md.
#
# Without a CUDA device it prints one line and exits 1, having run and written nothing.
# Environment (defaults in brackets):
#   PYTHON       [.venv/bin/python if present, else python3]
#   SCENE        [$SIMPLENERF_SHARED/data/nerf_llff_data/fern, SIMPLENERF_SHARED defaulting to ../shared]
#   RELEASE_SRC  [../SimpleNeRF/src: the src/ of a clone of the authors' release at c429746 (docs/equivalence.md);
#                 none there: step 3 is recorded as skipped]; RELEASE_GIT [none]: its git directory, if src/ has no
#                 data/ beside it
#   SIMPLENERF_LPIPS_WEIGHTS [$SIMPLENERF_SHARED/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz if present]
#   STEPS [20], WARMUP [5]: timed and untimed iterations of step 2; FIT_STEPS [500]; BUDGET [570]
#   WHEELS [.whl]: if that folder holds wheels, they are installed into /tmp/site first (the project's dependencies
#                  that a GPU machine's image lacks, e.g. jsonargparse, pycolmap, wandb, pandas for step 3)
set -uo pipefail

usage() { sed -n '2,5p' "$0" | sed 's/^# \{0,1\}//'; }
DRY_RUN=0 OUT=
while [ $# -gt 0 ]; do
  case $1 in
    --dry-run) DRY_RUN=1 ;;
    -h | --help) usage; exit 0 ;;
    -*) echo "gpu.sh: unknown option $1 (expected --dry-run, --help or an output folder)" >&2; exit 2 ;;
    *)
      [ -z "$OUT" ] || { echo "gpu.sh: one output folder expected, got $OUT and $1" >&2; exit 2; }
      OUT=$1 ;;
  esac
  shift
done
cd "$(dirname "$0")/../.."
if [ -z "${PYTHON:-}" ]; then
  if [ -x .venv/bin/python ]; then PYTHON=.venv/bin/python; else PYTHON=python3; fi
fi
SHARED=${SIMPLENERF_SHARED:-../shared}
SCENE=${SCENE:-$SHARED/data/nerf_llff_data/fern}
RELEASE_SRC=${RELEASE_SRC:-../SimpleNeRF/src}
RELEASE_GIT=${RELEASE_GIT:-}
OUT=${OUT:-runs/gpu/$(date -u +%Y-%m-%dT%H%M%SZ)}
STEPS=${STEPS:-20} WARMUP=${WARMUP:-5} FIT_STEPS=${FIT_STEPS:-500} BUDGET=${BUDGET:-570}
WHEELS=${WHEELS:-.whl}
LPIPS_NPZ=$SHARED/data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz
if [ -z "${SIMPLENERF_LPIPS_WEIGHTS:-}" ] && [ -f "$LPIPS_NPZ" ]; then export SIMPLENERF_LPIPS_WEIGHTS=$LPIPS_NPZ; fi
export WANDB_MODE=offline PYTHONUNBUFFERED=1
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}

data=(--data.init_args.scene_dir "$SCENE" --data.init_args.n_views 2 --data.init_args.factor 4)
bench=(-m simplenerf benchmark --config configs/llff.yaml --steps "$STEPS" --warmup "$WARMUP")
fit=(-m simplenerf fit --config configs/llff.yaml --config configs/overrides/budget/warmup_10.yaml "${data[@]}"
  --trainer.max_steps "$FIT_STEPS" --trainer.precision bf16-mixed --trainer.val_check_interval $((FIT_STEPS / 2))
  --checkpoint.every_n_train_steps "$FIT_STEPS" --trainer.default_root_dir "$OUT/fit" --overwrite true)
equivalence=(-m benchmarks.equivalence.check --release-src "$RELEASE_SRC" ${RELEASE_GIT:+--release-git "$RELEASE_GIT"}
  --scene-dir "$SCENE" --device cuda --views 2 3 4 --skip-data --trajectory-steps 100
  --work-dir "$OUT/release_equivalence_work" --out "$OUT/release_equivalence.md"
  --json "$OUT/logs/release_equivalence.json")

start=$SECONDS
step() {  # step NAME LIMIT_S [record options --] PYTHON_ARGS...: runs "$PYTHON" PYTHON_ARGS under the limit (and
  # what is left of BUDGET), output in logs/NAME.log, and records it (gpu_report record, with the record options)
  local name=$1 limit=$2; shift 2
  local rec=()
  while [ $# -gt 0 ] && [ "$1" != "--" ]; do rec+=("$1"); shift; done
  shift
  local left=$((BUDGET - (SECONDS - start)))
  [ "$limit" -le "$left" ] || limit=$left
  if [ "$DRY_RUN" = 1 ]; then
    printf '[%s, at most %s s] %q' "$name" "$limit" "$PYTHON"; printf ' %q' "$@"; printf '\n'
    return 0
  fi
  if [ "$limit" -le 0 ]; then
    "$PYTHON" -m benchmarks.speed.gpu_report record "$OUT" "$name" skipped 0 --note "no time left of BUDGET=$BUDGET s"
    echo "gpu.sh: $name skipped: no time left of the $BUDGET s budget" >&2
    return 1
  fi
  local t0=$SECONDS status
  timeout "$limit" "$PYTHON" "$@" > "$OUT/logs/$name.log" 2>&1
  status=$?
  "$PYTHON" -m benchmarks.speed.gpu_report record "$OUT" "$name" "$status" $((SECONDS - t0)) "${rec[@]}"
  if [ "$status" = 0 ]; then
    echo "$name done in $((SECONDS - t0)) s ($((SECONDS - start)) s in)"
  else
    echo "gpu.sh: $name ended with status $status (124: its ${limit} s limit), see $OUT/logs/$name.log" >&2
  fi
  return "$status"
}

if [ "$DRY_RUN" = 0 ]; then
  if ! "$PYTHON" -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)' 2> /dev/null; then
    echo "gpu.sh: no CUDA device (torch.cuda.is_available() is not True for $PYTHON): nothing run" >&2
    exit 1
  fi
  # the wheels after the check: a machine without CUDA gets nothing installed either
  if compgen -G "$WHEELS/*.whl" > /dev/null; then
    "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
      "$WHEELS"/*.whl && export PYTHONPATH=/tmp/site:$PYTHONPATH
  fi
  [ -f "$SCENE/poses_bounds.npy" ] || { echo "gpu.sh: no LLFF scene at $SCENE (set SCENE or SIMPLENERF_SHARED)" >&2; exit 2; }
  mkdir -p "$OUT/logs"
  "$PYTHON" - > "$OUT/logs/machine.json" <<'EOF'
import json, subprocess, time
import torch
from simplenerf.evaluation.evaluator import git_commit
p = torch.cuda.get_device_properties(0)
try:
    driver = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader", "-i", "0"],
                            capture_output=True, text=True, timeout=20).stdout.strip() or None
except (OSError, subprocess.SubprocessError):
    driver = None
print(json.dumps({"gpu": p.name, "memory_gib": round(p.total_memory / 2**30, 1), "sms": p.multi_processor_count,
                  "driver": driver, "torch": torch.__version__, "cuda": torch.version.cuda, "commit": git_commit(),
                  "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}))
EOF
  "$PYTHON" -m benchmarks.speed.gpu_report record "$OUT" machine 0 0 --from-json "$OUT/logs/machine.json"
  "$PYTHON" -c 'import json, sys; m = json.load(open(sys.argv[1]))
print(f"GPU: {m[\"gpu\"]}, {m[\"memory_gib\"]:.0f} GiB, {m[\"sms\"]} SMs, driver {m[\"driver\"]}; torch {m[\"torch\"]}, CUDA {m[\"cuda\"]}")' \
    "$OUT/logs/machine.json"
else
  echo "# dry run: would check for a CUDA device ($PYTHON: torch.cuda.is_available()), print the GPU's model, then run:"
fi

# W&B offline; a machine whose Python lacks wandb (a GPU machine given only the wheels it cannot do without) fits with
# no logger rather than failing at the logger's start (checked here, after WHEELS are installed).
fit_note=()
if ! "$PYTHON" -c 'import wandb' > /dev/null 2>&1; then
  fit+=(--trainer.logger false)
  fit_note=(--note "no logger: $PYTHON cannot import wandb")
  echo "# fit: $PYTHON cannot import wandb: the fit runs with --trainer.logger false (no W&B run)"
fi
step sfm 60 -- -m simplenerf sparse-depth --config configs/llff.yaml "${data[@]}"
step benchmark_fp32 55 --from-json "$OUT/logs/benchmark_fp32.log" -- \
  "${bench[@]}" --label fp32 --precision 32-true -- "${data[@]}"
step benchmark_tf32 55 --from-json "$OUT/logs/benchmark_tf32.log" -- \
  "${bench[@]}" --label tf32 --precision 32-true --tf32 -- "${data[@]}"
step benchmark_bf16 55 --from-json "$OUT/logs/benchmark_bf16.log" -- \
  "${bench[@]}" --label bf16-mixed --precision bf16-mixed -- "${data[@]}"
if [ -f "$RELEASE_SRC/Trainer01.py" ]; then
  step release_equivalence 110 --from-json "$OUT/logs/release_equivalence.json" -- "${equivalence[@]}"
elif [ "$DRY_RUN" = 1 ]; then
  echo "# release_equivalence: skipped (recorded as such): no release at RELEASE_SRC=$RELEASE_SRC"
else
  "$PYTHON" -m benchmarks.speed.gpu_report record "$OUT" release_equivalence skipped 0 \
    --note "no release at RELEASE_SRC=$RELEASE_SRC (docs/equivalence.md: a clone at c429746)"
  echo "gpu.sh: release_equivalence skipped: no release at RELEASE_SRC=$RELEASE_SRC" >&2
fi
step fit 150 --checkpoint "$OUT/fit/checkpoints/last.ckpt" ${fit_note[@]+"${fit_note[@]}"} -- "${fit[@]}"
if [ -f "$OUT/fit/checkpoints/last.ckpt" ] || [ "$DRY_RUN" = 1 ]; then
  step test 55 --test-summary "$OUT/fit/test/summary.json" -- \
    -m simplenerf test --config "$OUT/fit/config.yaml" --ckpt_path last
else
  "$PYTHON" -m benchmarks.speed.gpu_report record "$OUT" test skipped 0 --note "the fit wrote no last.ckpt"
fi

[ "$DRY_RUN" = 1 ] && exit 0
echo "total $((SECONDS - start)) s; figures in $OUT/results.jsonl"
"$PYTHON" -m benchmarks.speed.gpu_report summary "$OUT"
