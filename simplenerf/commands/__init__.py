"""`simplenerf <verb> ...` (also `python -m simplenerf <verb> ...`): every command of the project, one registry.

`VERBS` maps a verb to the function that runs it ("module:function", or "module" for its `main`; called with the
arguments after the verb, the Lightning verbs with the verb too, LightningCLI's subcommand) and the line `simplenerf
--help` shows. A verb's module parses its arguments with a `CommandParser` whose description (the module docstring)
has an example. Registering a verb is one line here, e.g. `"view": Verb(C + "view", "...", INSPECT)`; the
module is imported only when its verb runs, so `simplenerf --help` and the verbs that need no torch start at once.
Every verb runs under `simplenerf.run.console.run_tool`: bad input ends with one `simplenerf: error:` line and exit
status 2, a signal with one line and 128 + its number.

One spelling on every verb, the Lightning verbs': options in snake_case (`--depth_range`, `--dry_run`), a checkpoint
is `--ckpt_path`, and the verbs that read a run take the CLI's overrides (`simplenerf fit`'s options) among their own,
`--data.init_args.scene_dir DIR` as for `fit` (`split_overrides`). The spellings before (`--depth-range`, `--ckpt`,
overrides after `--`) still work, not shown in `--help`, with a note on stderr.
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


# The top-level keys of the CLI (LightningCLI's and simplenerf.run.cli's groups) that a verb reading a run takes as
# overrides with no dot in them: `--seed_everything 1`, `--model CLASS`; every dotted option (`--trainer.x`) is one too.
CLI_KEYS = ("seed_everything", "trainer", "model", "data", "optimizer", "lr_scheduler")


class CommandParser(argparse.ArgumentParser):
    """A verb's parser (`prog` "simplenerf <verb>"): `--help` shows its module's docstring (a description and an
    example); a bad option ends with one `simplenerf: error:` line and a hint, exit status 2, as for the Lightning
    verbs (`simplenerf.run.console.parser_error_line`).

    Options are spelled as the Lightning verbs' (snake_case; a kebab-case name is refused when the verb is built).
    Each option's kebab-case spelling and the spellings given as `old=` (`--ckpt` of `--ckpt_path`) are read as the
    option with a note on stderr, for the scripts written before; `--help` shows the one spelling."""

    def __init__(self, verb: str, doc: str | None, prog: str | None = None) -> None:
        self.old_spellings: dict[str, str] = {}  # a former spelling -> the option's (`--ckpt` -> `--ckpt_path`)
        super().__init__(prog=prog or f"{PROG} {verb}", description=doc,
                         formatter_class=argparse.RawDescriptionHelpFormatter)

    def add_argument(self, *names: str, old: Sequence[str] = (), **kwargs) -> argparse.Action:
        """argparse's, with the option's former spellings `old` (its kebab-case one is always taken)."""
        long = [n for n in names if n.startswith("--")]
        kebab = [n for n in long if "-" in n[2:]]
        if kebab:
            raise ValueError(f"{self.prog}: option {kebab[0]}: spell it {snake_case(kebab[0])} (the Lightning "
                             "verbs' spelling, that of every verb)")
        action = super().add_argument(*names, **kwargs)
        for name in long:
            if "_" in name:
                self.old_spellings[name.replace("_", "-")] = name
        self.old_spellings.update(dict.fromkeys(old, long[0] if long else names[0]))
        return action

    def parse_known_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None):
        """argparse's, with the former spellings read as the options' (up to a `--`)."""
        return super().parse_known_args(self.respelled(sys.argv[1:] if args is None else args), namespace)

    def respelled(self, args: Sequence[str]) -> list[str]:
        """`args` with every former spelling (`--ckpt X`, `--depth-range=1`) replaced by the option's, each noted
        once on stderr."""
        out, noted = list(args), set()
        for i, arg in enumerate(out):
            if arg == "--":
                break
            name, eq, value = arg.partition("=")
            new = self.old_spellings.get(name)
            if new is None:
                continue
            out[i] = new + eq + value
            if name not in noted:
                noted.add(name)
                sys.stderr.write(f"{self.prog}: note: {name} is spelled {new} now (as on every verb)\n")
        return out

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{PROG}: error: {message}\nhint: `{self.prog} --help` lists every option\n")
        sys.exit(2)


def snake_case(option: str) -> str:
    """`--depth-range` -> `--depth_range`."""
    return "--" + option[2:].replace("-", "_")


def split_overrides(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """A verb's own arguments and the overrides it passes to the CLI (those of `simplenerf fit`): every option of
    the CLI among them, dotted (`--data.init_args.scene_dir DIR`, `--trainer.max_steps=5`) or one of `CLI_KEYS`
    (`--seed_everything 1`), with its value (the next argument, unless the option has `=` or the next is an option),
    and everything after a `--` (the spelling before; both may be mixed)."""
    argv = list(argv)
    after: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, after = argv[:i], argv[i + 1 :]
    own, overrides = [], []
    i = 0
    while i < len(argv):
        arg = argv[i]
        name, eq, _ = arg.partition("=")
        key = name[2:]
        if name.startswith("--") and ("." in key or key in CLI_KEYS):
            takes_next = not eq and i + 1 < len(argv) and not argv[i + 1].startswith("--")
            overrides += argv[i : i + 1 + takes_next]
            i += 1 + takes_next
        else:
            own.append(arg)
            i += 1
    return own, overrides + after


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
