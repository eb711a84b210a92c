"""Runs `simplenerf visibility-masks` (simplenerf/commands/visibility_masks.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["visibility-masks", *sys.argv[1:]])
