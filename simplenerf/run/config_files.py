"""The config files a command is given: each must be readable YAML (one line naming the file otherwise), and a run's
saved `config.yaml` works as the --config of the next command (a resume, test, a tool): the subcommand's own keys that
do not apply are dropped, and class paths moved since the run was trained are read as the current ones."""

from __future__ import annotations

from pathlib import Path

import yaml

from simplenerf.errors import SimpleNeRFError
from simplenerf.run.resume import current_class_paths

# The arguments of a subcommand itself, not of the model, data or trainer: a fit saves them in <run>/config.yaml.
SUBCOMMAND_KEYS = ("ckpt_path", "weights_only", "overwrite", "allow_changes", "viewer", "viewer_port")
FIT_ONLY_KEYS = ("overwrite", "viewer", "viewer_port")


def without_subcommand_keys(args: list[str], drop: tuple[str, ...]) -> list[str]:
    """`args` with each `--config FILE` whose top level sets one of `drop` (a run's saved config.yaml) given as its
    YAML without those keys, so that a fit's record works as the --config of test, validate or a tool; a file that
    names a moved class path (`resume.MOVED_CLASS_PATHS`: a run trained before the move) is given with the current
    one."""
    out: list[str] = []
    i = 0
    while i < len(args):
        if args[i] == "--config" and i + 1 < len(args):
            out += ["--config", _config_without(args[i + 1], drop)]
            i += 2
            continue
        if args[i].startswith("--config="):
            out.append("--config=" + _config_without(args[i].split("=", 1)[1], drop))
        else:
            out.append(args[i])
        i += 1
    return out


def check_config_files(args: list[str]) -> None:
    """Each `--config FILE` given must be readable YAML: else one line naming the file, line and column (the
    parser itself reads the text and would lose the file's name)."""
    paths = [args[i + 1] for i, arg in enumerate(args[:-1]) if arg == "--config"]
    paths += [arg.split("=", 1)[1] for arg in args if arg.startswith("--config=")]
    for path in paths:
        if not Path(path).is_file():
            continue
        try:
            yaml.safe_load(Path(path).read_text())
        except UnicodeDecodeError:
            raise SimpleNeRFError(f"config file {path} is not text (UTF-8 YAML)") from None
        except OSError as e:
            raise SimpleNeRFError(f"cannot read config file {path}: {e.strerror or e}") from None
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)  # only yaml's MarkedYAMLError subclasses have these
            where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "somewhere"
            what = " ".join(str(part) for part in (getattr(e, "context", None), getattr(e, "problem", None)) if part)
            raise SimpleNeRFError(f"config file {path}: YAML syntax error at {where}: {what or e}") from None


def _config_without(path: str, drop: tuple[str, ...]) -> str:
    file = Path(path)
    if not file.is_file():
        return path  # a YAML string, or a missing file the parser reports
    try:
        config = yaml.safe_load(file.read_text())
    except (yaml.YAMLError, UnicodeDecodeError):
        return path
    if not isinstance(config, dict):
        return path
    upgraded = current_class_paths(config)
    if upgraded == config and not any(key in config for key in drop):
        return path
    return yaml.safe_dump({k: v for k, v in upgraded.items() if k not in drop}, sort_keys=False)
