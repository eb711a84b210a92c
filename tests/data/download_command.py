"""`simplenerf download DATASET ARGS` run in the test's own process (stubs and monkeypatches apply), for the
download tests."""

from __future__ import annotations

from simplenerf.commands import main


def run_download(dataset: str, *args: str) -> int:
    """Runs `simplenerf download <dataset> ARGS`; its exit status."""
    try:
        main(["download", dataset, *args])
    except SystemExit as e:
        return int(e.code or 0)
    return 0
