"""Runs `simplenerf rescore` (simplenerf/commands/rescore.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["rescore", *sys.argv[1:]])
