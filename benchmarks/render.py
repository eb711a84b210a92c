"""Times full-frame rendering of test views (the data module's predict frames, in order); prints ONE JSON line, e.g.

    python benchmarks/render.py --config configs/llff.yaml --frames 1 [--ckpt runs/llff/checkpoints/last.ckpt] \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern

The first test view of fern at factor 4 is frame 0, 1008x756 = 762048 rays. The JSON holds s/frame (median, min,
max, all), rays/s, field evaluations/s (coarse + (coarse + fine) samples per ray: 256 in the paper config), peak RSS
and peak CUDA memory. Without --ckpt the weights are the initial ones: the same work per ray, other pictures. Rays
per forward pass: `--model.chunk` (after `--`). `--warmup W` renders W untimed frames first.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from simplenerf.benchmark import render_main  # noqa: E402

if __name__ == "__main__":
    render_main(description=__doc__)
