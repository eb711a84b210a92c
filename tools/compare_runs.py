"""Prints the test metrics of runs side by side, e.g.

    python tools/compare_runs.py SimpleNeRF=runs/demo DS-NeRF=runs/demo_dsnerf
"""

from __future__ import annotations

import sys

from simplenerf.evaluation.compare import load_summaries, markdown_table


def main() -> None:
    if len(sys.argv) < 2 or any("=" not in a for a in sys.argv[1:]):
        sys.exit(__doc__)
    runs = dict(arg.split("=", 1) for arg in sys.argv[1:])
    print(markdown_table(load_summaries(runs)))


if __name__ == "__main__":
    main()
