"""`simplenerf <verb> ...` (also `python -m simplenerf <verb> ...`): every command of the project, one registry.

`VERBS` maps a verb to the function that runs it ("module:function", or "module" for its `main`; called with the
arguments after the verb, the Lightning verbs with the verb too, LightningCLI's subcommand) and the line `simplenerf
--help` shows. A verb's module parses its arguments with a `CommandParser` whose description (the module docstring)
has an example. Registering a verb is one line here, e.g. `"view": Verb(C + "view", "...", INSPECT)`; the
module is imported only when its verb runs, so `simplenerf --help` and the verbs that need no torch start at once.
Every verb runs under `simplenerf.run.console.run_tool`: bad input ends with one `simplenerf: error:` line and exit
status 2, a signal with one line and 128 + its number.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NoReturn

from simplenerf.run.console import PROG, run_tool


@dataclass(frozen=True)
class Verb:
    target: str  # "module:function" or "module" (its main): the function taking the verb's arguments (list[str])
    summary: str  # one line of `simplenerf --help`
    task: str  # the group `simplenerf --help` lists it under (one of TASKS)


# The groups of `simplenerf --help`, in a run's order: data in, training and scoring, looking at a run, experiments.
TASKS = ("data", "train and score", "inspect a trained run", "experiments and results")


LIGHTNING_VERBS = ("fit", "validate", "test", "predict")  # LightningCLI's subcommands (simplenerf.run.cli)

LIGHTNING = "simplenerf.run.cli:lightning_main"
DATA, TRAIN, INSPECT, EXPERIMENTS = TASKS
C = "simplenerf.commands."
VERBS: dict[str, Verb] = {
    "download": Verb(C + "download", "the paper's data: LLFF, RealEstate-10K clips (checked, resumed)", DATA),
    "synthetic": Verb(C + "synthetic", "write the built-in synthetic scene", DATA),
    "process-data": Verb(C + "process_data", "own photos -> a scene folder (SfM with pycolmap)", DATA),
    "sparse-depth": Verb(C + "sparse_depth", "compute and cache a config's SfM sparse depth", DATA),
    "fit": Verb(LIGHTNING, "train a run from a config (resume it with --ckpt_path last)", TRAIN),
    "validate": Verb(LIGHTNING, "score a run's validation view", TRAIN),
    "test": Verb(LIGHTNING, "render and score every test frame into <run>/test", TRAIN),
    "predict": Verb(LIGHTNING, "render the test frames", TRAIN),
    "export-depth": Verb(C + "export_depth", "a dense NeRF's depth of every frame (reference depth)", TRAIN),
    "visibility-masks": Verb(C + "visibility_masks", "a scene's test-frame visibility masks", TRAIN),
    "rescore": Verb(C + "rescore", "score a tested run again from its saved renders", TRAIN),
    "heldout-depth": Verb(C + "heldout_depth", "a trained run's depth error at held-out SfM points", TRAIN),
    "view": Verb(C + "view", "the web viewer of a run: renders, depths, masks from any camera", INSPECT),
    "render-video": Verb(C + "render_video", "video of a trained run along the camera path", INSPECT),
    "export-geometry": Verb(C + "export_geometry", "a trained run's depth maps and point cloud", INSPECT),
    "run-history": Verb(C + "run_history", "what a run logged, read back from its W&B files (CSV)", INSPECT),
    "sweep": Verb(C + "sweep", "scenes x views x models x seeds as jobs (SLURM, local), then a table", EXPERIMENTS),
    "results": Verb(C + "results", "tested runs side by side, over seeds, beside the paper's rows", EXPERIMENTS),
    "benchmark": Verb(C + "benchmark", "seconds per training step and peak memory of a config", EXPERIMENTS),
}

DESCRIPTION = (
    "SimpleNeRF (SIGGRAPH Asia 2023): Neural Radiance Fields from 2 to 4 photos, regularised by simpler augmented "
    "models. Start from a config in configs/, e.g. `simplenerf fit --config configs/demo.yaml`."
)


class CommandParser(argparse.ArgumentParser):
    """A verb's parser (`prog` "simplenerf <verb>"): `--help` shows its module's docstring (a description and an
    example); a bad option ends with one `simplenerf: error:` line and a hint, exit status 2, as for the Lightning
    verbs (`simplenerf.run.console.parser_error_line`)."""

    def __init__(self, verb: str, doc: str | None, prog: str | None = None) -> None:
        super().__init__(prog=prog or f"{PROG} {verb}", description=doc,
                         formatter_class=argparse.RawDescriptionHelpFormatter)

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{PROG}: error: {message}\nhint: `{self.prog} --help` lists every option\n")
        sys.exit(2)


def split_overrides(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """A verb's own arguments and, after `--`, the overrides it passes to the CLI (those of `simplenerf fit`)."""
    argv = list(argv)
    if "--" not in argv:
        return argv, []
    i = argv.index("--")
    return argv[:i], argv[i + 1 :]


def overview() -> str:
    """`simplenerf --help`: every verb with its line, grouped by task."""
    width = max(map(len, VERBS))
    lines = [f"usage: {PROG} <command> [options]    (`{PROG} <command> --help`: its options and an example)",
             f"       {PROG} --version", "", textwrap.fill(DESCRIPTION, 100)]
    for task in TASKS:
        lines += ["", f"{task}:"]
        lines += [f"  {name:<{width}}  {verb.summary}" for name, verb in VERBS.items() if verb.task == task]
    return "\n".join(lines)


def version() -> str:
    """`simplenerf --version`: the package's version (its installed metadata's, else the source's)."""
    from importlib import metadata

    from simplenerf import __version__

    try:
        installed = metadata.version("simplenerf")
    except metadata.PackageNotFoundError:
        installed = __version__
    return f"{PROG} {installed}"


def main(argv: Sequence[str] | None = None) -> None:
    """The `simplenerf` command: runs the verb `argv[0]` with the rest (None: sys.argv[1:])."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(overview())
        return
    if argv[0] in ("-V", "--version"):
        print(version())
        return
    name = "fit" if argv[0].startswith("-") else argv[0]  # LightningCLI's options before its subcommand: `-c FILE fit`
    if name not in VERBS:
        close = difflib.get_close_matches(name, list(VERBS), n=1)
        guess = f"; did you mean {close[0]}?" if close else ""
        sys.stderr.write(f"{PROG}: error: unknown command {name!r}{guess} (`{PROG} --help` lists the commands)\n")
        sys.exit(2)
    # Imported before run_tool quietens the libraries, so that their log handlers exist to be filtered.
    module, _, function = VERBS[name].target.partition(":")
    run = getattr(importlib.import_module(module), function or "main")
    args = argv if name in LIGHTNING_VERBS else argv[1:]
    run_tool(lambda: run(args), PROG)
