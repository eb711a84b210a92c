"""Runs `simplenerf export-depth` (simplenerf/commands/export_depth.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["export-depth", *sys.argv[1:]])
