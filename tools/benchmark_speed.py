"""Seconds per training iteration and peak memory for a config, e.g.

    python tools/benchmark_speed.py --config configs/llff.yaml --rays 1024 --precision 32-true \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern

Everything after `--` is passed to the CLI as overrides. Prints one JSON line. Run one measurement per process:
peak memory is per process.
"""

from __future__ import annotations

import argparse
import json
import sys

from simplenerf.benchmark import time_training
from simplenerf.cli import make_cli, split_overrides


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True)
    parser.add_argument("--rays", type=int, help="random rays per iteration (overrides the config)")
    parser.add_argument("--precision", default="32-true", help="Lightning precision, e.g. 32-true or bf16-mixed")
    parser.add_argument("--steps", type=int, default=3, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=1, help="untimed iterations first")
    args = parser.parse_args(own)
    if args.rays:
        overrides += ["--data.init_args.rays_per_batch", str(args.rays)]
    cli = make_cli(["--config", args.config, "--trainer.logger", "false", *overrides], run=False)
    result = time_training(cli.model, cli.datamodule, args.steps, args.warmup, args.precision)
    print(json.dumps({"config": args.config, "overrides": overrides, "rays": cli.datamodule.rays_per_batch,
                      "precision": args.precision, **result}))


if __name__ == "__main__":
    main()
