"""Profiles one training iteration after W warm-up iterations (torch.profiler, CPU; + CUDA on a GPU): prints a
markdown table of the top operators by self CPU time, then ONE JSON line with the iteration's wall, user and system
time and minor page faults. E.g. the release's variant B on one thread:

    OMP_NUM_THREADS=1 python benchmarks/profile_step.py --config configs/llff.yaml --warmup 2 \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern \
           --data.init_args.rays_per_batch 256 --data.init_args.sparse_rays_per_batch 256

The profiler adds overhead per operator: compare shares within one profile, and take s/it from train_step.py.
torch.profiler's "CPU time" is the wall-clock time of each operator on the CPU side, so on a shared machine it
includes waiting for a core: the JSON's `cpu_over_wall` (user + system time / wall time) says how much of the
iteration the process actually ran.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from simplenerf.benchmark import profile_main  # noqa: E402

if __name__ == "__main__":
    profile_main(description=__doc__)
