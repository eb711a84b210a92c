"""Tested runs as a table in the layout of the paper's Tables 1-2 (logic: simplenerf/reporting/tables.py and
records.py), e.g.

    python tools/results_table.py SimpleNeRF='runs/llff/*' DS-NeRF=runs/dsnerf_fern_2v --paper llff --csv table.csv
    python tools/results_table.py SimpleNeRF=runs/fern_2v SimpleNeRF=runs/horns_2v --scores both --depth
    python tools/results_table.py SimpleNeRF='runs/llff/*' --per-scene
    python tools/results_table.py ../shared/reference_scores/test10{1,2,3}1 --paper llff --depth

Rows: models in the order given (several runs may share a NAME: the row averages the test frames of their scenes, as
the paper does; --per-scene: one table per scene); column groups: 2 / 3 / 4 views, each LPIPS, SSIM, PSNR (--depth:
also depth MAE, SROCC). Masked scores by default, as in the paper. A folder of the authors' test runs (QA_Scores/ with
per-frame CSVs, e.g. ../shared/reference_scores/test1011) is read as is, as the row "SimpleNeRF (release)".
--csv FILE writes the shown values in long format: table, model, source, n_views, metric, value, scenes, frames.
"""

from __future__ import annotations

import sys

from simplenerf.reporting.tables import main

if __name__ == "__main__":
    sys.exit(main())
