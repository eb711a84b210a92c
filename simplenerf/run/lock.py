"""One writer per run folder: `<run>/.simplenerf.lock`, held with `fcntl.flock` by the process that writes the run.

The kernel releases the lock when its holder exits in any way (an error, a signal, SIGKILL, a crash), so a lock left
by a killed process is recognised as stale and simply taken over; the file itself stays (removing it would race with
a process that has just opened it) and holds the holder's pid, host, start time and command, for the error line of
a second `fit` or `test` started into the same folder.

The lock is taken before anything in the folder is read, moved or deleted (the checkpoint a command starts from, the
checkpoints `fit --overwrite true` deletes, earlier test results): a second command into a busy folder changes
nothing there. A command that created the folder itself and then stops on bad input removes it again
(`release_run_folder`), so that a refused command leaves no run folder behind. The tools that write into a trained
run (`render-video`, `export-geometry`, `visibility-masks`, ...) take the lock of the run folder their output lies in
(`lock_output`).
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
_created: dict[Path, tuple[Path | None, bool]] = {}  # folder -> (outermost folder this process created, lock file too)


def holder_description(text: str) -> str:
    """`pid N on HOST since TIME: COMMAND` from a lock file's contents (or what is known of it)."""
    try:
        info = json.loads(text)
        return f"pid {info['pid']} on {info['host']} since {info['started']}: {info['command']}"
    except (ValueError, KeyError, TypeError):
        return "a process that left no description"


def lock_run_folder(folder: Path, command: str, instead: str = "use another --trainer.default_root_dir") -> None:
    """Takes the lock of run folder `folder` (created if needed) for this process, until it exits. `instead`: the
    other choice the error line offers.

    Raises:
        RunFolderError: another live process holds it (the line names it: pid, host, command), or the folder cannot
            be created.
    """
    folder = Path(folder)
    key = folder.resolve()
    if key in _held:
        return
    outermost = next((p for p in reversed([folder, *folder.parents]) if not p.exists()), None)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunFolderError(f"cannot write to the run folder {folder}: {e.strerror or e}") from None
    path = folder / LOCK_NAME
    while True:
        new_file = not path.exists()
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise RunFolderError(f"cannot write to the run folder {folder}: {e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = holder_description(os.pread(fd, 65536, 0).decode(errors="replace"))
            os.close(fd)
            raise RunFolderError(
                f"the run folder {folder} is in use by {holder}; wait for it to finish, or {instead}"
            ) from None
        try:  # the file locked must still be the one at `path` (a refused command may have just removed it)
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "started": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": command}
    os.ftruncate(fd, 0)
    os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
    _held[key] = fd
    _created[key] = (outermost, new_file)


def release_run_folder(folder: Path) -> None:
    """Gives up the lock of `folder` taken by `lock_run_folder`. The lock file and the folders this process created
    are removed again, as far as they hold nothing else: a command refused after taking the lock leaves nothing."""
    key = Path(folder).resolve()
    fd = _held.pop(key, None)
    if fd is None:
        return
    outermost, new_file = _created.pop(key, (None, False))
    if new_file:
        try:
            (key / LOCK_NAME).unlink()
        except OSError:
            pass
    os.close(fd)
    if outermost is None:
        return
    outermost = outermost.resolve()
    for path in (key, *key.parents):
        try:
            path.rmdir()
        except OSError:  # not empty (another process's file) or gone: leave it
            return
        if path == outermost:
            return


def run_folder_of(path: Path) -> Path | None:
    """The run folder that `path` (a file or folder, existing or not) is or lies in: the nearest of it and its
    parents that holds a run's lock file, or `checkpoints/` beside the `config.yaml` of a fit; None if there is none
    (an output outside any run)."""
    path = Path(path).absolute()
    for folder in (path, *path.parents):
        if (folder / LOCK_NAME).is_file() or ((folder / "checkpoints").is_dir() and (folder / "config.yaml").is_file()):
            return folder
    return None


def lock_output(out: Path, option: str = "--out") -> None:
    """Takes the lock of the run folder that the output `out` of a tool lies in (`run_folder_of`), if any, before the
    tool writes it: a tool refuses to write into a run that a fit or test is writing (the one-line "in use" error,
    which offers another `option`), and a fit into a folder a tool is writing waits its turn likewise.

    Raises:
        RunFolderError: another live process holds the lock.
    """
    folder = run_folder_of(out)
    if folder is not None:
        lock_run_folder(folder, command_line(), instead=f"write elsewhere with {option}")


def command_line() -> str:
    """This process's command, for the lock file."""
    argv = list(sys.argv)
    if argv and argv[0].endswith(os.path.join("simplenerf", "__main__.py")):
        argv = ["simplenerf", *argv[1:]]
    return shlex.join(argv)[:2000]
