"""Runs `simplenerf heldout-depth` (simplenerf/commands/heldout_depth.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["heldout-depth", *sys.argv[1:]])
