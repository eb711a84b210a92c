"""Errors the command line reports as one clear line (`simplenerf.run.console.run_tool`), instead of a traceback."""

from __future__ import annotations

import tempfile
from pathlib import Path


class SimpleNeRFError(Exception):
    """Base class: bad input or setup the user can fix; the message says what and where."""

    exit_status = 2
    """The process's exit status when the command line stops on this error (2: bad input, as argparse)."""


class DataError(SimpleNeRFError, ValueError):
    """A scene on disk is missing, incomplete or inconsistent, or a split cannot be made from it."""


class SfMError(DataError):
    """Structure from motion (`simplenerf.sfm`) cannot place cameras or points from these images (too few views, no
    features or verified matches, poses the images contradict); the message says why and what to try."""


class CheckpointError(SimpleNeRFError):
    """A checkpoint is missing, unreadable (truncated, not a checkpoint) or does not fit the model."""


class RunFolderError(SimpleNeRFError):
    """The run folder cannot be written, or writing it would destroy an earlier run's checkpoints."""


class TrainingDiverged(SimpleNeRFError):
    """The training loss became NaN or infinite; the checkpoints written before it are kept."""

    exit_status = 1


class Stopped(SimpleNeRFError):
    """A signal (SIGINT, SIGTERM) stopped the command before it finished; exit status 128 + the signal's number."""

    def __init__(self, message: str, signum: int) -> None:
        super().__init__(message)
        self.signum = signum
        self.exit_status = 128 + int(signum)


def absent(path: Path, folder: bool) -> str:
    """Why `path` is not the folder (`folder`) or file expected, for an error line after its name: it "does not
    exist", or it is the other kind."""
    path = Path(path)
    if not path.exists():
        return "does not exist"
    if path.is_dir():
        return "is a folder, not a file"
    return "is a file, not a folder" if folder else "is not a regular file"


def unwritable(folder: Path) -> str | None:
    """Why `folder` cannot be created and written (a file written there, then deleted), or None if it can: the reason
    both the run-folder check and process-data's output check put in their error."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        return str(e.strerror or e)
    return None
