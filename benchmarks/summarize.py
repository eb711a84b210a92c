"""Markdown table of a side-by-side sitting: the release's driver.py JSON files and our train_step.py JSON lines.

    python benchmarks/summarize.py results/side_by_side/*.json

Per variant (our runs carry it as `label`) and our precision: pooled s/it of the release (its discarded warm-up
iterations and short sparse-depth batches left out, as ../shared/tools/official_timing/summarize.py) and of ours
(timed iterations after warm-up), the ratio release / ours (above 1: ours is faster) and each side's peak RSS.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from simplenerf.benchmark import side_by_side_table  # noqa: E402

if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        sys.exit(__doc__)
    print(side_by_side_table(sys.argv[1:]))
