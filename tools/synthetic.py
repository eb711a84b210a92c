"""Runs `simplenerf synthetic` (simplenerf/commands/synthetic.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["synthetic", *sys.argv[1:]])
