"""Tested runs as a table in the layout of the paper's Tables 1-2 (logic: simplenerf/tables.py), e.g.

    python tools/results_table.py SimpleNeRF='runs/llff/*' DS-NeRF=runs/dsnerf_fern_2v --paper llff --csv table.csv
    python tools/results_table.py SimpleNeRF=runs/fern_2v SimpleNeRF=runs/horns_2v --scores both --depth
    python tools/results_table.py SimpleNeRF='runs/llff/*' --per-scene

Rows: models in the order given (several runs may share a NAME: the row averages their scenes); column groups: 2 / 3 /
4 views, each LPIPS, SSIM, PSNR (--depth: also depth MAE, SROCC). Masked scores by default, as in the paper.
--csv FILE writes the shown values in long format: table, model, source, n_views, metric, value, scenes.
"""

from __future__ import annotations

import sys

from simplenerf.evaluation.tables import main

if __name__ == "__main__":
    sys.exit(main())
