"""Computes and caches the sparse (SfM) depth of a config's training views, so that `fit` starts at once, e.g.

    python tools/precompute_sparse_depth.py --config configs/dsnerf.yaml \
        --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern --data.init_args.n_views 2

Takes the same arguments as `python -m simplenerf fit`; prints the points and reprojection error per view.
"""

from __future__ import annotations

import sys

from simplenerf.cli import run_tool
from simplenerf.lightning_cli import make_cli


def main() -> None:
    cli = make_cli([*sys.argv[1:], "--trainer.logger", "false"], run=False)
    dm = cli.datamodule
    if not dm.sparse_rays_per_batch:
        sys.exit("this config does not use sparse depth (data.init_args.sparse_rays_per_batch is 0)")
    dm.setup("fit")  # computes (or finds) the cache and prints a line per view


if __name__ == "__main__":
    run_tool(main, "precompute_sparse_depth")  # bad input or Ctrl-C: one line, no traceback
