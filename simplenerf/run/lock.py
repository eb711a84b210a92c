"""One writer per run folder: `<run>/.simplenerf.lock`, held with `fcntl.flock` by the process that writes the run.

The kernel releases the lock when its holder exits in any way (an error, a signal, SIGKILL, a crash), so a lock left
by a killed process is recognised as stale and simply taken over; the file itself stays (removing it would race with
a process that has just opened it) and holds the holder's pid, host, start time and command, for the error line of
a second `fit` or `test` started into the same folder.
"""

from __future__ import annotations

import fcntl
import json
import os
import shlex
import socket
import sys
from datetime import datetime, timezone
from pathlib import Path

from simplenerf.errors import RunFolderError

LOCK_NAME = ".simplenerf.lock"

_held: dict[Path, int] = {}  # folder -> file descriptor, held until the process exits


def holder_description(text: str) -> str:
    """`pid N on HOST since TIME: COMMAND` from a lock file's contents (or what is known of it)."""
    try:
        info = json.loads(text)
        return f"pid {info['pid']} on {info['host']} since {info['started']}: {info['command']}"
    except (ValueError, KeyError, TypeError):
        return "a process that left no description"


def lock_run_folder(folder: Path, command: str) -> None:
    """Takes the lock of run folder `folder` (created if needed) for this process, until it exits.

    Raises:
        RunFolderError: another live process holds it (the line names it: pid, host, command).
    """
    folder = Path(folder)
    key = folder.resolve()
    if key in _held:
        return
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise RunFolderError(f"cannot create the lock file {path}: {e.strerror or e}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = holder_description(os.pread(fd, 65536, 0).decode(errors="replace"))
        os.close(fd)
        raise RunFolderError(
            f"the run folder {folder} is in use by {holder}; wait for it to finish, or use another "
            "--trainer.default_root_dir"
        ) from None
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "started": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": command}
    os.ftruncate(fd, 0)
    os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
    _held[key] = fd


def command_line() -> str:
    """This process's command, for the lock file."""
    argv = list(sys.argv)
    if argv and argv[0].endswith(os.path.join("simplenerf", "__main__.py")):
        argv = ["simplenerf", *argv[1:]]
    return shlex.join(argv)[:2000]
