"""A tiny run trained through the real command line with `--viewer true`, and the viewer of it (in this process)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tests.run.test_cli import run, run_args


@pytest.fixture(scope="session")
def viewer_run(tmp_path_factory) -> tuple[Path, str]:
    """(the run folder of a 2-step fit of the tiny demo model with the viewer open, the fit's stdout)."""
    tmp = tmp_path_factory.mktemp("viewer_run")
    proc = run("fit", *run_args(tmp), "--trainer.max_steps", "2", "--viewer", "true", "--viewer_port", "0")
    return tmp / "run", proc.stdout


@pytest.fixture(scope="module")
def viewer(viewer_run):
    """`simplenerf view RUN --port 0` of that run, opened here; closed after the module."""
    from simplenerf.commands.view import open_viewer

    argv, sys.argv = sys.argv, sys.argv[:1]  # the CLI reads these arguments, not pytest's
    try:
        opened = open_viewer([str(viewer_run[0]), "--port", "0"])
    finally:
        sys.argv = argv
    yield opened
    opened.close()
