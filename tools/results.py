"""Runs `simplenerf results` (simplenerf/commands/results.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["results", *sys.argv[1:]])
