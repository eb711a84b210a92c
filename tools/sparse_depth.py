"""Runs `simplenerf sparse-depth` (simplenerf/commands/sparse_depth.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["sparse-depth", *sys.argv[1:]])
