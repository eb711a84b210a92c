"""Runs `simplenerf render-video` (simplenerf/commands/render_video.py; `--help`: its options, an example)."""

import sys

from simplenerf.commands import main

if __name__ == "__main__":
    main(["render-video", *sys.argv[1:]])
