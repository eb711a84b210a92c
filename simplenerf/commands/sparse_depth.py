r"""Computes and caches the sparse (SfM) depth of a config's train views, so that `fit` starts at once (DS-NeRF's
sparse depth, simplenerf.sfm.sparse_depth), e.g.

    simplenerf sparse-depth --config configs/dsnerf.yaml \
        --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern --data.init_args.n_views 2

Takes the same arguments as `simplenerf fit` (`simplenerf fit --help` lists them); prints the points and
reprojection error per view.
"""

from __future__ import annotations

from collections.abc import Sequence

from simplenerf.errors import SimpleNeRFError
from simplenerf.run.cli import make_cli


def main(argv: Sequence[str]) -> None:
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: simplenerf sparse-depth --config FILE [fit options]\n\n{__doc__}")
        return
    cli = make_cli([*argv, "--trainer.logger", "false"], run=False)
    dm = cli.datamodule
    if not dm.sparse_rays_per_batch:
        raise SimpleNeRFError("this config does not use sparse depth (data.init_args.sparse_rays_per_batch is 0)")
    dm.setup("fit")  # computes (or finds) the cache and prints a line per view
