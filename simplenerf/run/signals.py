"""What SIGINT (Ctrl-C) and SIGTERM (a scheduler's stop, SLURM's preemption) do to a command (docs/running.md).

`install()` (`simplenerf.run.console.run_tool` calls it first) makes both signals raise `Interrupted` where the program
is, so cleanups run (`finally`, `except BaseException`: process-data's partial folder, the sparse-depth cache's
temporary file) and the command line prints one line and exits with 128 + the signal's number: 130 for SIGINT, 143
for SIGTERM, the shell's convention that Lightning's own `sys.exit` on Ctrl-C does not follow (it exits 1).

While Lightning runs a loop it has its own SIGTERM handler (`lightning.pytorch.trainer.connectors.signal_connector`),
which calls ours after its own: the signal is then left to Lightning, which stops the loop at the end of the current
batch (`trainer.received_sigterm` -> `SIGTERMException`); `fit` then writes last.ckpt (`run.callbacks.Checkpointing`).
SIGINT is forwarded to that path as a SIGTERM to the process itself. A second signal stops at once. `validate`,
`test` and `predict` (`at_step_end` False) stop at once too: a batch of theirs is a whole frame, which can take a
minute to render on a CPU (longer than a scheduler waits after SIGTERM), and there is nothing to save; `test` removes
its partial results (`Evaluator.on_exception`). SIGUSR1, Lightning's SLURM requeue signal
(`SLURMEnvironment(auto_requeue=True)`), is left to Lightning.
"""

from __future__ import annotations

import os
import signal
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """Raised by a signal outside Lightning's loops, or by a second signal: stop now."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


received: int | None = None
"""The first signal this process received (None: none)."""
_forwarded = False  # a SIGINT re-sent as SIGTERM to Lightning's handler, which will call ours once more
at_step_end = True
"""Whether a signal during a Lightning loop waits for the end of the batch (`fit`: a resumable checkpoint) rather
than stopping at once; the CLI sets it per subcommand."""


def exit_status(signum: int) -> int:
    """The exit status of a command stopped by `signum` (130 for SIGINT, 143 for SIGTERM)."""
    return 128 + int(signum)


def name(signum: int) -> str:
    return signal.Signals(signum).name


def _lightning_handles_sigterm() -> bool:
    """True while a Lightning trainer runs a loop: its handler, not ours, is registered for SIGTERM."""
    return signal.getsignal(signal.SIGTERM) is not _handler


def _handler(signum: int, frame: FrameType | None) -> None:
    global received, _forwarded
    if signum == signal.SIGTERM and _forwarded:  # our own forwarded SIGINT, back through Lightning's handler
        _forwarded = False
        return
    first = received is None
    if first:
        received = signum
    if first and at_step_end and _lightning_handles_sigterm():
        if signum != signal.SIGTERM:
            _forwarded = True
            os.kill(os.getpid(), signal.SIGTERM)
        return  # Lightning stops the loop at the end of the batch
    raise Interrupted(signum)


def install() -> None:
    """Handles SIGINT and SIGTERM as the module docstring says (in the main thread; elsewhere signals cannot be
    handled and nothing changes)."""
    global received, _forwarded, at_step_end
    received, _forwarded, at_step_end = None, False, True
    for signum in SIGNALS:
        try:
            signal.signal(signum, _handler)
        except ValueError:  # not the main thread
            return
