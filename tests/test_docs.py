"""The docs cannot drift: every `simplenerf` verb and `--option`, every file path, config and `python -m` module that
README.md and docs/*.md name (in code spans and fenced code) exists.

Verbs come from the command registry (`simplenerf.commands.VERBS`); a verb's options from what its parser answers to
`--help` (its option lines and usage, not its examples), the Lightning verbs' from LightningCLI's parser, with the
options of each data module from `--data.help <class>`. An option named on its own (`--video.frames`) must be an
option of some verb. Paths are relative to the repository root, or, for modules, to the package (`model/nerf.py`).
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import io
import re
from functools import cache
from pathlib import Path

import pytest

from simplenerf.commands import LIGHTNING_VERBS, VERBS, main

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
SPAN = re.compile(r"`([^`\n]+)`")
COMMAND = re.compile(r"(?:python -m simplenerf|(?<![\w./{,-])simplenerf)\s+([a-z][a-z-]*)(?=\s|$)([^|;&`#]*)")
OPTION = re.compile(r"(?<![\w-])(--[A-Za-z][\w.\-]*[\w])")
PATH = re.compile(r"(?<![\w./<>{}$~-])((?:\.ci|[A-Za-z_][\w-]*)(?:/[\w.*{},\-]+)+/?)")
ROOTS = (".ci", "configs", "docs", "tools", "benchmarks", "simplenerf", "tests")
PACKAGE_PARTS = tuple(p.name for p in (REPO / "simplenerf").iterdir() if (p / "__init__.py").is_file())
# Paths the docs name that are outputs of a command, not files of the repository.
OUTPUTS = {"docs/images/demo.png": "`make demo` draws it (tools/demo.sh)"}


def code_lines() -> list[tuple[str, int, str]]:
    """(page, line number, code) of every line of code in the pages: fenced blocks (a line continued with a backslash
    joined to the next) and inline code spans. History is written as plain text: code names what exists now."""
    out = []
    for page in PAGES:
        text = page.read_text()
        for m in FENCE.finditer(text):
            first = text.count("\n", 0, m.start(1)) + 1
            for i, line in enumerate(m.group(1).replace("\\\n", " \n").splitlines()):
                out.append((page.name, first + i, line))
        fenced = [range(m.start(), m.end()) for m in FENCE.finditer(text)]
        for m in SPAN.finditer(text):
            if not any(m.start() in r for r in fenced):
                out.append((page.name, text.count("\n", 0, m.start()) + 1, m.group(1)))
    return out


def commands() -> list[tuple[str, int, str, list[str]]]:
    """(page, line, verb, options) of every `simplenerf <verb> ...` in the docs' code."""
    return [(page, n, m.group(1), OPTION.findall(m.group(2))) for page, n, line in code_lines()
            for m in COMMAND.finditer(line)]


def help_text(*argv: str) -> str:
    """What `simplenerf <argv> --help` prints (in this process)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()), contextlib.suppress(SystemExit):
        main([*argv, "--help"])
    return out.getvalue()


def declared(help_output: str) -> set[str]:
    """The options a parser declares: in its usage and its option lines, not in the examples of its description."""
    usage, _, rest = help_output.partition("\n\n")
    lines = [line for line in rest.splitlines() if line.lstrip().startswith("-")]
    return set(OPTION.findall(usage)) | {o for line in lines for o in OPTION.findall(line)}


@cache
def config_classes() -> tuple[str, ...]:
    """Every class the shipped configs name by class_path (what a `--<group>.help <class>` can list)."""
    pattern = re.compile(r"class_path:\s*([\w.]+)")
    names = {m for f in (REPO / "configs").rglob("*.yaml") for m in pattern.findall(f.read_text())}
    return tuple(sorted(names | {"simplenerf.data.synthetic.SyntheticDataModule"}))


@cache
def options(verb: str) -> frozenset[str]:
    """Every option of `simplenerf <verb>` (and of its sub-commands, `download llff`)."""
    text = help_text(verb)
    found = declared(text)
    for choices in re.findall(r"\{([\w,-]+)\}", text.splitlines()[0]):
        for sub in choices.split(","):
            found |= declared(help_text(verb, sub))
    return frozenset(found)


@cache
def parameters() -> frozenset[str]:
    """The constructor arguments of every class the configs name (over its bases: arguments passed on by **kwargs),
    which jsonargparse turns into the options of a subclass-typed group (`--data.init_args.factor`)."""
    names = set()
    for path in config_classes():
        module, _, name = path.rpartition(".")
        for cls in getattr(importlib.import_module(module), name).__mro__:
            if "__init__" in vars(cls):
                names |= set(inspect.signature(cls.__init__).parameters) - {"self", "args", "kwargs"}
    return frozenset(names)


def known(option: str, verb: str) -> bool:
    """Whether `simplenerf <verb>` takes `option`; verbs that load a run also take the Lightning verbs' options (the
    overrides they hand to LightningCLI)."""
    lightning = verb if verb in LIGHTNING_VERBS else "fit"
    if option in options(verb) or option in options(lightning):
        return True
    # Under a subclass-typed group (one with `--<group>.help`: `--data`, `--model.nerf`, `--trainer.callbacks`), an
    # argument of a class it may take (`--data.init_args.factor`, `--model.nerf.fine.init_args.tv_weight`).
    parts = option[2:].split(".")
    groups = [".".join(parts[:i]) for i in range(1, len(parts))]
    return any(f"--{g}.help" in options(lightning) for g in groups) and parts[-1] in parameters()


def test_every_documented_verb_exists():
    unknown = [f"{page}:{n}: simplenerf {verb}" for page, n, verb, _ in commands() if verb not in VERBS]
    assert not unknown, "verbs the docs name but `simplenerf` does not have:\n" + "\n".join(unknown)


def test_every_documented_option_of_a_verb_exists():
    unknown = [f"{page}:{n}: simplenerf {verb} {o}" for page, n, verb, opts in commands() if verb in VERBS
               for o in opts if not known(o, verb)]
    assert not unknown, "options the docs give a verb but its parser does not have:\n" + "\n".join(unknown)


def test_every_option_named_on_its_own_exists():
    """An option in Lightning's spelling (dotted or snake_case, `--video.frames 3`) in code without a verb belongs to
    some verb. (Kebab-case options on their own are left out: most are other programs', sbatch's or a benchmark
    script's.)"""
    unknown = [f"{page}:{n}: {o}" for page, n, line in code_lines() if not COMMAND.search(line)
               for o in OPTION.findall(line) if ("." in o or "_" in o) and not any(known(o, v) for v in VERBS)]
    assert not unknown, "options the docs name that no verb has:\n" + "\n".join(unknown)


def expand(path: str) -> list[str]:
    """A path with shell braces (`fern_{simplenerf,dsnerf}.yaml`) as its alternatives."""
    m = re.search(r"\{([^{}]*)\}", path)
    if not m:
        return [path]
    return [p for alt in m.group(1).split(",") for p in expand(path[: m.start()] + alt + path[m.end() :])]


def exists(path: str) -> bool:
    """Relative to the repository root, or to the package for its modules; a glob matches something."""
    path = path.rstrip("/")
    return any(any(base.glob(path)) if "*" in path else (base / path).exists() for base in (REPO, REPO / "simplenerf"))


def paths() -> list[tuple[str, int, str]]:
    """(page, line, path) of every path in the docs' code that names a file or folder of the repository."""
    out = []
    for page, n, line in code_lines():
        for m in PATH.finditer(line):
            path = m.group(1).rstrip(".,:;)")
            first = path.split("/")[0]
            if first in ROOTS or (first in PACKAGE_PARTS and Path(path).suffix == ".py"):
                out += [(page, n, p) for p in expand(path)]
    return out


def test_the_path_check_finds_paths():
    """The check below would pass vacuously if the pattern missed paths: these are named and exist."""
    named = {path for _, _, path in paths()}
    assert {"configs/demo.yaml", "configs/cpu/fern_dsnerf.yaml", "method/objective.py", "tests/custom_term.py"} <= named


def test_every_documented_path_exists():
    missing = [f"{page}:{n}: {path}" for page, n, path in paths() if path not in OUTPUTS and not exists(path)]
    assert not missing, "paths the docs name that do not exist:\n" + "\n".join(missing)


def test_every_documented_python_module_exists():
    module = re.compile(r"python -m ([\w.]*\w)(?![\w.<])")
    modules = [(page, n, m) for page, n, line in code_lines() for m in module.findall(line)]
    missing = [f"{page}:{n}: python -m {m}" for page, n, m in modules if m not in ("pip", "venv", "pytest")
               and not (REPO / f"{m.replace('.', '/')}.py").exists()
               and not (REPO / m.replace(".", "/") / "__main__.py").exists()]
    assert modules and not missing, "modules the docs run that do not exist:\n" + "\n".join(missing)


@pytest.mark.parametrize(("verb", "option"), [("fit", "--ckpt_path"), ("fit", "--data.init_args.scene_dir"),
                                              ("sweep", "--dry_run")])
def test_a_renamed_option_would_be_caught(verb, option):
    """The check is not vacuous: these options are documented with their verb and known; renamed, they would not be."""
    assert any(v == verb and option in opts for _, _, v, opts in commands())
    assert known(option, verb) and not known(option + "_renamed", verb)
