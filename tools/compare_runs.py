"""Prints the test metrics of runs side by side, e.g.

    python tools/compare_runs.py SimpleNeRF=runs/demo DS-NeRF=runs/demo_dsnerf

A name given several times (e.g. one run per seed) becomes one row of mean ± standard deviation over its runs:

    python tools/compare_runs.py SimpleNeRF=runs/s0 SimpleNeRF=runs/s1 DS-NeRF=runs/d0 DS-NeRF=runs/d1
"""

from __future__ import annotations

import sys
from pathlib import Path

from simplenerf.reporting.compare import load_summaries, markdown_table, seed_table


def main() -> None:
    if len(sys.argv) < 2 or any("=" not in a for a in sys.argv[1:]):
        sys.exit(__doc__)
    pairs = [arg.split("=", 1) for arg in sys.argv[1:]]
    names = [name for name, _ in pairs]
    if len(set(names)) == len(names):
        print(markdown_table(load_summaries(dict(pairs))))
        return
    groups: dict[str, list[dict]] = {}
    for name, path in pairs:
        groups.setdefault(name, []).append(load_summaries({name: Path(path)})[name])
    print(seed_table(groups))


if __name__ == "__main__":
    main()
