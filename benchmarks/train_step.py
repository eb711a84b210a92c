"""Times N training iterations of any config after W warm-up iterations; prints ONE JSON line, e.g.

    python benchmarks/train_step.py --config configs/llff.yaml --steps 3 --warmup 2 --precision 32-true \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern \
           --data.init_args.rays_per_batch 256 --data.init_args.sparse_rays_per_batch 256

Everything after `--` goes to the CLI as overrides (`python -m simplenerf fit` arguments). `--tf32` allows TF32
matrix products in fp32 (CUDA). The JSON holds s/it (median, min, max, all), rays/s, field evaluations/s, peak RSS and
peak CUDA memory, CPU user/system time and page faults per iteration, and the losses computed. Field evaluations per
ray: coarse samples x (1 + augmentations) + (coarse + fine) samples for the fine field (paper config: 64 x 3 + 192 =
384), times the rays (random + sparse-depth) of an iteration; see simplenerf/benchmark/measure.py. The config's warm-up
schedule is not applied: every loss is computed at its configured weight (the cost of a step after the warm-up).
One measurement per process: peak memory is per process.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from simplenerf.benchmark import train_step_main  # noqa: E402

if __name__ == "__main__":
    train_step_main(description=__doc__)
