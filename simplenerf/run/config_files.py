"""The `--config` files a command is given: each must be readable YAML without a key given twice (one line naming
the file, the key and both lines), and a run's saved `config.yaml` works as a config of any verb: the subcommand's own
keys dropped where they do not apply, moved class paths read as the current ones (`resume.MOVED_CLASS_PATHS`), and a
run folder that was copied or moved read where the file is."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import yaml
from lightning.pytorch.utilities import rank_zero_only

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


class DuplicateKey(Exception):
    def __init__(self, key: Any, first: int, second: int) -> None:
        super().__init__(key)
        self.key, self.first, self.second = key, first, second


class UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (`DuplicateKey`: the key and both lines),
    which YAML libraries accept with the later value."""


def _unique_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            if key in seen:
                raise DuplicateKey(key, seen[key], key_node.start_mark.line + 1)
            seen[key] = key_node.start_mark.line + 1
        except TypeError:  # an unhashable key: the loader itself says so
            pass
    return loader.construct_mapping(node, deep)


UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def check_config_files(args: list[str]) -> None:
    """Each `--config FILE` given must be readable YAML without a key given twice: else one line naming the file,
    line and column (the parser itself reads the text and would lose the file's name)."""
    paths = [args[i + 1] for i, arg in enumerate(args[:-1]) if arg == "--config"]
    paths += [arg.split("=", 1)[1] for arg in args if arg.startswith("--config=")]
    for path in paths:
        if not Path(path).is_file():
            continue
        try:
            yaml.load(Path(path).read_text(), Loader=UniqueKeyLoader)  # noqa: S506 (a SafeLoader)
        except DuplicateKey as e:
            raise SimpleNeRFError(f"config file {path}: key {e.key!r} is given twice in one mapping, at line "
                                  f"{e.first} and line {e.second} (the later would silently win); keep one") from None
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
    moved = _moved_run_folder(file, upgraded)
    if moved is not None:  # a copied or moved run: its config.yaml reads and writes the run where the file is
        upgraded = {**upgraded, "trainer": {**upgraded["trainer"], "default_root_dir": moved}}
    if upgraded == config and not any(key in config for key in drop):
        return path
    return yaml.safe_dump({k: v for k, v in upgraded.items() if k not in drop}, sort_keys=False)


def _moved_run_folder(file: Path, config: dict) -> str | None:
    """The folder of `file` when it is a run's saved config.yaml (beside the run's checkpoints/) whose
    trainer.default_root_dir names another folder (the run was copied or moved since): said on stderr."""
    trainer = config.get("trainer")
    if file.name != "config.yaml" or not isinstance(trainer, dict) or not (file.parent / "checkpoints").is_dir():
        return None
    recorded = trainer.get("default_root_dir")
    if not isinstance(recorded, str) or Path(recorded).resolve() == file.parent.resolve():
        return None
    if rank_zero_only.rank == 0:
        print(f"simplenerf: {file} is the config of a run trained in {recorded}; using the run where the file is, "
              f"{file.parent}", file=sys.stderr, flush=True)
    return str(file.parent)
