"""Runs `simplenerf process-data` (simplenerf/commands/process_data.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["process-data", *sys.argv[1:]])
