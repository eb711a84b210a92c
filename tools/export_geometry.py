"""Runs `simplenerf export-geometry` (simplenerf/commands/export_geometry.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["export-geometry", *sys.argv[1:]])
