"""Runs `simplenerf run-history` (simplenerf/commands/run_history.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["run-history", *sys.argv[1:]])
