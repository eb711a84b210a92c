"""What the command line prints: a parser error as one line and a hint, no library noise (deprecation warnings,
advertising tips), and Lightning's info lines held back until the run's inputs have passed their checks."""

from __future__ import annotations

import difflib
import importlib
import inspect
import logging
import re
import signal
import sys
import warnings
from collections.abc import Callable
from typing import Any

from simplenerf.errors import SimpleNeRFError, Stopped
from simplenerf.run import signals

PROG = "simplenerf"


TYPE_WORDS = {
    "PositiveInt": "a positive integer", "NonNegativeInt": "an integer >= 0", "PositiveFloat": "a positive number",
    "NonNegativeFloat": "a number >= 0", "int": "an integer", "float": "a number", "bool": "true or false",
    "str": "a string", "Port": "a port number 0-65535",
}


def _cause(detail: str, given: str | None) -> str:
    """A jsonargparse type error as `expected <type>, got <value>` (the key is added by the caller)."""
    if match := re.match(r"Not of type (\w+): (.*?) does not conform to restriction", detail):
        return f"expected {TYPE_WORDS.get(match.group(1), match.group(1))}, got {match.group(2)}"
    if match := re.match(r"Not of type (\w+): .*", detail):
        if quoted := re.search(r": ('.*')$", detail):
            value = quoted.group(1)
        else:
            value = given if given is not None and not given.startswith(("{", "Namespace(")) else "another value"
        return f"expected {TYPE_WORDS.get(match.group(1), match.group(1))}, got {value}"
    if match := re.match(r"Expected a <class '(\w+)'>\.? Got value: (.*)$", detail):
        return f"expected {TYPE_WORDS.get(match.group(1), match.group(1))}, got {match.group(2)}"
    return detail


def _union_cause(lines: list[str], given: str | None) -> str | None:
    """A value that matches none of a Union's types (e.g. `--trainer.precision fp8`) as `expected one of <the
    choices>, got <value>`: every Literal's values and the other types in words; None if the message lists none."""
    subtypes = next((line.removeprefix("Subtypes: ") for line in lines if line.startswith("Subtypes: ")), None)
    if subtypes is None:
        return None
    choices: list[str] = []
    for literal, kind in re.findall(r"Literal\[([^\]]*)\]|<class '([\w.]+)'>", subtypes):
        if literal:
            choices += [value.strip().strip("'\"") for value in literal.split(",")]
        elif kind:
            choices.append("null" if kind == "NoneType" else TYPE_WORDS.get(kind, kind))
    if not choices:
        return None
    choices = list(dict.fromkeys(choices))
    return f"expected one of {', '.join(choices)}; got {given if given is not None else 'another value'}"


def _nested_key(lines: list[str], start: int) -> tuple[list[str], str | None, str | None]:
    """Below a `Problem with given class_path` line: the keys of the nested `Parser key "k":` lines, the innermost
    cause and the value given there."""
    keys: list[str] = []
    cause = given = None
    for line in lines[start:]:
        if match := re.match(r'Parser key "([^"]+)":\s*(.*)$', line):
            keys.append(match.group(1))
            if match.group(2):
                cause = match.group(2)
                break
            continue
        if not keys:
            break
        if line.startswith(("Does not validate against any of", "Subtypes:", "Errors:", "Given value type:",
                            "Expected a path but")):
            continue
        cause = line
        break
    if keys:
        for line in lines[start:]:
            if line.startswith("Given value: ") and not line.startswith("Given value: NestedArg"):
                given = line.removeprefix("Given value: ")
                break
    return keys, cause, given


def parser_error_line(message: str, parser: Any) -> tuple[str, str]:
    """One line for a parser error message of jsonargparse (often many lines of nested causes), and a hint: the
    closest valid name when an option or a class name is mistyped, else where the options are listed. A wrong value
    keeps its cause: the full key, the expected type and the given value; a YAML error its line and column."""
    lines = [line.strip().lstrip("- ").strip() for line in message.strip().splitlines()]
    lines = [line for line in lines if line]
    key, detail = None, lines[0] if lines else message
    if match := re.match(r'Parser key "([^"]+)":\s*(.*)$', detail):
        key, detail = match.group(1), match.group(2)
    suggestion = None
    for i, line in enumerate(lines):
        if match := re.match(r"Problem with given class_path '([^']+)':\s*(.*)$", line):
            class_path, cause = match.group(1), match.group(2) or (lines[i + 1] if i + 1 < len(lines) else "")
            nested, inner, given = _nested_key(lines, i + 1)
            deeper = re.match(r"Problem with given class_path '([^']+)':\s*(.*)$", inner or "")
            if nested and deeper:  # an argument's own class_path is wrong (a mistyped field class)
                key = ".".join([key, "init_args", *nested]) if key else ".".join(nested)
                at = lines.index(inner, i + 1)
                class_path, cause = deeper.group(1), deeper.group(2) or (lines[at + 1] if at + 1 < len(lines) else "")
                detail = f"class_path {class_path}: {cause}"
            elif nested and inner:  # a wrong value of one of the class's arguments
                key = ".".join([key, "init_args", *nested]) if key else ".".join(nested)
                detail = f"{_cause(inner, given)} ({class_path})"
            else:
                detail = f"class_path {class_path}: {cause}"
            suggestion = _class_suggestion(class_path, cause)
            break
    else:
        if not detail and len(lines) > 1:
            detail = lines[1]
        given = next((line.removeprefix("Given value: ") for line in lines if line.startswith("Given value: ")), None)
        if detail.startswith("Expected a path but") and "Errors:" in lines:  # a class_path of the wrong kind
            reasons = [line for line in lines[lines.index("Errors:") + 1:]
                       if not line.startswith(("Expected a <class 'NoneType'>", "Given value"))]
            detail = f"class_path {given}: {reasons[0]}" if reasons else detail
        elif detail.startswith("Does not validate against any of the Union subtypes"):
            detail = _union_cause(lines, given) or detail
        else:
            detail = _cause(detail, given)
    if detail.startswith("Problems parsing config") and len(lines) > 1:  # YAML: keep where and what
        detail = " ".join(lines).replace('in "<unicode string>", ', "")
    if match := re.match(r"unrecognized arguments: (.*)$", detail):
        options = [s for action in parser._actions for s in action.option_strings]
        unknown = [token.split("=")[0] for token in match.group(1).split() if token.startswith("--")]
        for token in unknown:
            if close := difflib.get_close_matches(token, options, n=1, cutoff=0.6):
                suggestion = close[0]
                break
    prog = parser.prog.replace(" [options]", "")
    listing = f"`{prog} --help` lists every option"
    hint = f"hint: did you mean {suggestion}? ({listing})" if suggestion else f"hint: {listing}"
    return (f"--{key}: {detail}" if key else detail), hint


def _class_suggestion(class_path: str, cause: str) -> str | None:
    """The closest existing name for a mistyped class (in its module) or a mistyped constructor option."""
    try:
        if match := re.search(r"module '([^']+)' has no attribute '([^']+)'", cause):
            module = importlib.import_module(match.group(1))
            names = [n for n, v in vars(module).items() if inspect.isclass(v)]
            close = difflib.get_close_matches(match.group(2), names, n=1)
            return f"{match.group(1)}.{close[0]}" if close else None
        if match := re.search(r"Option '([^']+)' is not accepted", cause):
            module_name, _, class_name = class_path.rpartition(".")
            cls = getattr(importlib.import_module(module_name), class_name)  # the config's class_path, by name
            # Options of the whole chain of constructors (a subclass may pass **kwargs on to its base).
            names = {name for klass in cls.__mro__ if "__init__" in vars(klass)
                     for name in inspect.signature(klass.__init__).parameters} - {"self", "args", "kwargs"}
            close = difflib.get_close_matches(match.group(1), sorted(names), n=1)
            return close[0] if close else None
    except (ImportError, AttributeError, ValueError, TypeError):
        return None
    return None


class _Hold(logging.Filter):
    def __init__(self, handler: logging.Handler) -> None:
        super().__init__()
        self.handler, self.records, self.holding = handler, [], True

    def filter(self, record: logging.LogRecord) -> bool:
        if self.holding:
            self.records.append(record)
        return not self.holding


class HeldLogs:
    """Holds back the records of Lightning's log handlers until `release()` (which emits them, once); records never
    released (the command stopped on an error first) are dropped."""

    def __init__(self) -> None:
        names = ("lightning.pytorch", "lightning.fabric")
        self.holds = [_Hold(handler) for name in names for handler in logging.getLogger(name).handlers]
        for hold in self.holds:
            hold.handler.addFilter(hold)

    def release(self, emit: bool = True) -> None:
        for hold in self.holds:
            hold.handler.removeFilter(hold)
            hold.holding = False
            for record in hold.records if emit else []:
                hold.handler.handle(record)
        self.holds = []


class _DropTips(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "Tip:" not in record.getMessage()


def quiet_libraries() -> None:
    """Keeps a normal run's output to what the user needs: no deprecation warnings of libraries (simplenerf's own
    stay), no advertising tips from Lightning, no warning that a resumed run's checkpoint folder is not empty."""
    for category in (DeprecationWarning, PendingDeprecationWarning, FutureWarning):
        warnings.filterwarnings("ignore", category=category)
        warnings.filterwarnings("default", category=category, module=r"simplenerf(\.|$)")
    # Checked by the CLI before the run: the folder has checkpoints only when fit resumes from them.
    warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is not empty")
    # SimpleNeRF optimises manually, one update per step: a step's checkpoint holds the weights after its update, which
    # is what a resume continues from (Lightning warns about exactly that).
    warnings.filterwarnings("ignore", message=r"Using ModelCheckpoint with manual optimization")
    # W&B's asyncio manager leaves a coroutine behind when a command stops at once on a signal (test, validate);
    # Python would warn about it at exit, after the command's one line.
    warnings.filterwarnings("ignore", message=r"coroutine 'AsyncioManager\._wrap' was never awaited",
                            category=RuntimeWarning)
    for name in ("lightning.pytorch", "lightning.fabric"):
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(_DropTips())


# Errors of libraries that mean bad input, reported as one line like `SimpleNeRFError`: (module, class). Looked up only
# where the module is loaded (one that is not cannot have raised), so a command that needs no torch starts at once.
LIBRARY_INPUT_ERRORS = (
    ("simplenerf.metrics.lpips", "LPIPSWeightsNotFound"),
    ("lightning.fabric.utilities.exceptions", "MisconfigurationException"),
)


def _input_errors() -> tuple[type[BaseException], ...]:
    # By name, so that this module imports neither library (see LIBRARY_INPUT_ERRORS).
    loaded = [getattr(sys.modules[module], name) for module, name in LIBRARY_INPUT_ERRORS if module in sys.modules]
    return (SimpleNeRFError, *loaded)


def run_tool(main_function: Callable[[], None], name: str = PROG) -> None:
    """Runs a command's main; bad input ends with one `<name>: error:` line and exit status 2 (a diverged training:
    1); a SIGINT or SIGTERM with one line and 128 + the signal's number (`simplenerf.run.signals`; docs/running.md)."""
    quiet_libraries()
    signals.install()
    try:
        main_function()
    except (KeyboardInterrupt, SystemExit, Exception) as e:
        if isinstance(e, _input_errors()):
            print(f"{name}: error: {e}", file=sys.stderr)
            sys.exit(e.exit_status if isinstance(e, SimpleNeRFError) else 2)
        # After a signal, any error is its consequence: a library that was running native code (pycolmap's SfM) may
        # turn the pending interrupt into its own exception. Without a signal, only KeyboardInterrupt is a stop.
        if signals.received is None and not isinstance(e, KeyboardInterrupt):
            raise
        signum = signals.received or (e.signum if isinstance(e, Stopped) else None) or signal.SIGINT
        print(f"{name}: error: stopped by {signals.name(signum)} before it finished", file=sys.stderr)
        sys.exit(signals.exit_status(signum))
