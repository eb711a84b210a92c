"""The command line: `python -m simplenerf {fit,validate,test,predict,sweep,process-data} ...` (also the `simplenerf`
script pip installs), and what the tools in tools/ share with it: one `error:` line and an exit status instead of a
traceback (`run_tool`), a tool's own arguments apart from the CLI's (`split_overrides`). The Lightning commands are
`simplenerf.lightning_cli`'s (its docstring says what every run gets and how a run is checked before it starts).
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable

from lightning.pytorch.utilities.exceptions import MisconfigurationException

from simplenerf import interrupts
from simplenerf.console import PROG, quiet_libraries
from simplenerf.errors import SimpleNeRFError, Stopped
from simplenerf.lightning_cli import make_cli
from simplenerf.metrics.lpips import LPIPSWeightsNotFound


def run_tool(main_function: Callable[[], None], name: str) -> None:
    """Runs an entry point's main; bad input ends with one `<name>: error:` line and exit status 2 (a diverged
    training: 1), as in `main`; a SIGINT or SIGTERM with one line and 128 + the signal's number
    (`simplenerf.interrupts`; docs/running.md)."""
    quiet_libraries()
    interrupts.install()
    try:
        main_function()
    except (SimpleNeRFError, LPIPSWeightsNotFound, MisconfigurationException) as e:
        print(f"{name}: error: {e}", file=sys.stderr)
        sys.exit(e.exit_status if isinstance(e, SimpleNeRFError) else 2)
    except (KeyboardInterrupt, SystemExit, Exception) as e:
        # After a signal, any error is its consequence: a library that was running native code (pycolmap's SfM) may
        # turn the pending interrupt into its own exception. Without a signal, only KeyboardInterrupt is a stop.
        if interrupts.received is None and not isinstance(e, KeyboardInterrupt):
            raise
        signum = interrupts.received or (e.signum if isinstance(e, Stopped) else None) or signal.SIGINT
        print(f"{name}: error: stopped by {interrupts.name(signum)} before it finished", file=sys.stderr)
        sys.exit(interrupts.exit_status(signum))


def split_overrides(argv: list[str]) -> tuple[list[str], list[str]]:
    """A tool's own arguments and, after `--`, the overrides it passes to the CLI."""
    if "--" not in argv:
        return argv, []
    i = argv.index("--")
    return argv[:i], argv[i + 1 :]


def main(args: list[str] | None = None) -> None:
    """Entry point; bad input ends with one `error:` line and exit status 2 instead of a traceback."""
    argv = sys.argv[1:] if args is None else args
    if argv[:1] == ["sweep"]:  # scenes x views x models x seeds as jobs (simplenerf.experiments), not a Lightning one
        from simplenerf.experiments.command import main as sweep

        run_tool(lambda: sweep(argv[1:]), PROG)
        return
    if argv[:1] == ["process-data"]:  # photos -> an LLFF-layout scene (simplenerf.sfm.photos); not a Lightning command
        from simplenerf.sfm.photos import main as process_data

        run_tool(lambda: process_data(argv[1:]), PROG)
        return
    run_tool(lambda: make_cli(args), PROG)
