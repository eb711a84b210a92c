"""Seconds per training iteration and peak memory for a config; an alias of benchmarks/train_step.py that also takes
`--rays R` (random rays per iteration, overriding the config), e.g.

    python tools/benchmark_speed.py --config configs/llff.yaml --rays 1024 --precision 32-true \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern

Everything after `--` is passed to the CLI as overrides. Prints one JSON line (see benchmarks/README.md). Run one
measurement per process: peak memory is per process.
"""

from __future__ import annotations

import argparse
import sys

from simplenerf.benchmark import train_step_main
from simplenerf.cli import split_overrides


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--rays", type=int, help="random rays per iteration (overrides the config)")
    known, rest = parser.parse_known_args(own)
    if known.rays:
        overrides += ["--data.init_args.rays_per_batch", str(known.rays)]
    train_step_main([*rest, "--", *overrides], description=__doc__)


if __name__ == "__main__":
    main()
