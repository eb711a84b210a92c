"""A resumed run is a continuation of the run (docs/running.md): `RunRecord` keeps in every checkpoint what a resume
needs besides Lightning's own state (weights, optimiser, LR schedule, loop counters):

- the global random state (torch, numpy, Python; CUDA where present), as it was after the last training step, set
  again before the first step after the resume (Lightning's `_collect_rng_states` / `_set_rng_states`);
- the run's data and model settings (`run_settings`): a resume whose settings differ from the run's stops with one
  line listing the differences (`setting_changes`), unless each is allowed with `--allow_changes`; `test` checks
  that it scores the scene (and train views) the checkpoint trained on (`check_run_settings`). The scene is the same
  scene by its content (`scene_digest`), wherever its folder is now (`scene_moved`).

The random-ray order continues too: `data.datasets.RandomRays` skips the batches the run has already drawn
(`SceneDataModule.train_dataloader` reads the resumed step). The loss-weight schedule is a function of the step
(`run.callbacks.LossWeightSchedule`), so it continues by itself.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import sys
import typing
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.fabric.utilities.seed import _collect_rng_states, _set_rng_states
from lightning.pytorch.utilities import rank_zero_only

from simplenerf.data.scene import Scene, SceneDataModule
from simplenerf.errors import CheckpointError

RECORD_KEY = "simplenerf_run"

# Data settings that do not change what a run trains on: where files are found or cached (the scene itself is
# compared by its content, `scene_digest`, and by its folder only in a run recorded before the digest), worker
# processes, and evaluation-only inputs.
IGNORED_DATA = ("root", "scene_dir", "sparse_depth_cache", "num_workers", "reference_depth_dir")
# Model settings that change memory use, not results (up to float rounding).
IGNORED_MODEL = ("chunk", "rays_per_backward")
# The setting that identifies a scene by its content (`scene_digest`).
DIGEST_KEY = "scene_digest"
# What `test` checks: the scored scene and its split are the trained ones.
TEST_KEYS = ("scene", DIGEST_KEY, "train_frames", "data_class")


# Modules whose classes moved (issue 37: the run machinery into simplenerf.run, the LightningModule and its optimiser
# into simplenerf.method, the validation and video callbacks into simplenerf.run.callbacks): a run's config.yaml or
# checkpoint written before names the old class paths, read as the new ones.
MOVED_CLASS_PATHS = {
    "simplenerf.callbacks.": "simplenerf.run.callbacks.",
    "simplenerf.loggers.": "simplenerf.run.loggers.",
    "simplenerf.optim.": "simplenerf.method.optim.",
    "simplenerf.module.": "simplenerf.method.module.",
    "simplenerf.viz.renders.ValidationRenders": "simplenerf.run.callbacks.ValidationRenders",
    "simplenerf.viz.video.TrainingVideo": "simplenerf.run.callbacks.TrainingVideo",
    "simplenerf.viewer.callback.": "simplenerf.run.callbacks.viewer.",
}


def current_class_paths(value: Any) -> Any:
    """`value` (a config or recorded settings: dicts, lists, strings) with every moved class path (MOVED_CLASS_PATHS)
    replaced by where the class lives now; everything else as it is."""
    if isinstance(value, dict):
        return {k: current_class_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [current_class_paths(v) for v in value]
    if isinstance(value, str):
        for old, new in MOVED_CLASS_PATHS.items():
            if value.startswith(old) and "." not in value[len(old):].strip("."):
                return new + value[len(old):]
    return value


def _plain(value: Any) -> Any:
    """JSON-safe copy (paths and other objects become strings)."""
    return json.loads(json.dumps(value, default=str))


def scene_digest(scene: Scene) -> str:
    """A scene's content as a resume compares it: the first 16 hex digits of the SHA-256 of its frames' image names
    and cameras as its files give them (`Scene.file_cameras`: LLFF's poses_bounds.npy, a RealEstate-10K clip's
    lines), so the same whatever the split and on any machine. The same scene in another folder (moved or copied)
    has the same digest; other poses or other images (names) do not. Pixels are not read again: a scene whose image
    files were replaced under the same names is not told apart. A format that does not give `file_cameras`: the
    loaded cameras (scaled and recentred on the train views) and bounds, rounded to 5 decimals."""
    digest = hashlib.sha256(json.dumps([str(name) for name in scene.views.names]).encode())
    if scene.file_cameras is not None:
        arrays = [np.asarray(scene.file_cameras, dtype=np.float64)]
    else:
        loaded = (scene.views.c2w, scene.views.intrinsics, scene.bounds)
        arrays = [np.round(np.asarray(a.detach().cpu() if isinstance(a, torch.Tensor) else a, dtype=np.float64), 5)
                  + 0.0 for a in loaded]  # + 0.0: no -0.0, whose bytes differ from 0.0's
    for array in arrays:
        digest.update(str(array.shape).encode() + np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]


def run_settings(config: Any, datamodule: Any) -> dict[str, Any]:
    """What identifies a run's training data and model: the data module's class, its arguments (except
    `IGNORED_DATA`), the scene it reads (`cache_key()`: the resolved folder, and `scene_digest`: its content), its
    train frames and size, and the model's arguments (except `IGNORED_MODEL`). `config` is the subcommand's parsed
    config (a jsonargparse Namespace or a dict)."""
    config = config.as_dict() if hasattr(config, "as_dict") else dict(config)  # jsonargparse Namespace or dict
    data = config.get("data") or {}
    init_args = dict(data.get("init_args") or {}) if isinstance(data, dict) else {}
    settings: dict[str, Any] = {
        "data_class": data.get("class_path") if isinstance(data, dict) else type(datamodule).__name__,
        "data": {k: v for k, v in init_args.items() if k not in IGNORED_DATA},
        "model": {k: v for k, v in (config.get("model") or {}).items() if k not in IGNORED_MODEL},
    }
    if isinstance(datamodule, SceneDataModule) and datamodule.scene is not None:
        scene = datamodule.scene
        settings["scene"] = datamodule.cache_key()
        settings[DIGEST_KEY] = scene_digest(scene)
        settings["train_frames"] = list(scene.split.train)
        settings["size"] = [int(scene.views.height), int(scene.views.width)]
    return _plain(settings)


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Dotted keys of the leaves; a list of objects (e.g. `model.augmentations`) by index, other lists whole."""
    if isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
        value = {str(i): item for i, item in enumerate(value)}
    if isinstance(value, dict) and value:
        out: dict[str, Any] = {}
        for key, item in value.items():
            out.update(_flatten(item, f"{prefix}.{key}" if prefix else str(key)))
        return out
    return {prefix: value}


NO_DEFAULT = object()


def _parameter(cls: type, name: str) -> tuple[Any, Any]:
    """(default, class) of `__init__` argument `name` of class `cls` (a dataclass's too), or of a base class that
    the `__init__` passes `**kwargs` on to; (NO_DEFAULT, None) where it has no default or there is no such argument.
    The class is the annotation where it resolves to one, else the default's."""
    for owner in (k for k in cls.__mro__ if k is not object and "__init__" in vars(k)):
        parameters = inspect.signature(owner.__init__).parameters
        if name in parameters:
            default = parameters[name].default
            if default is inspect.Parameter.empty:
                return NO_DEFAULT, None
            try:
                kind = typing.get_type_hints(owner.__init__).get(name)
            except (NameError, TypeError):  # an annotation that does not resolve: the default's class
                kind = None
            return default, kind if isinstance(kind, type) else type(default)
        if not any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
            break
    return NO_DEFAULT, None


def setting_default(settings: dict[str, Any], key: str, classes: dict[str, type]) -> Any:
    """The value the current code gives setting `key` (a dotted key of `run_settings`, e.g.
    `model.objective.coarse_fine_supervision` or `model.augmentations.0.init_args.min_ndc_z`) when it is not given:
    its argument's default, found by following the settings' `class_path`s down from `classes` (the classes of the
    top-level keys, e.g. {"model": SimpleNeRF, "data": LLFFDataModule}); `NO_DEFAULT` where there is none."""
    root, *path = key.split(".")
    cls, node = classes.get(root), settings.get(root)
    for i, part in enumerate(path):
        last = i == len(path) - 1
        if isinstance(node, dict) and "class_path" in node and part in ("class_path", "init_args"):
            if last or part == "class_path":
                return NO_DEFAULT
            try:
                module, _, name = str(node["class_path"]).rpartition(".")
                cls = getattr(importlib.import_module(module), name)
            except (ImportError, AttributeError, ValueError):
                return NO_DEFAULT
            node = node.get("init_args") or {}
            continue
        if isinstance(node, list):  # an element of a list of objects: its class comes with its class_path
            if last or not part.isdigit() or int(part) >= len(node):
                return NO_DEFAULT
            cls, node = None, node[int(part)]
            continue
        if not isinstance(cls, type):
            return NO_DEFAULT
        default, kind = _parameter(cls, part)
        if last:
            return default
        cls, node = kind, node.get(part) if isinstance(node, dict) else None
    return NO_DEFAULT


def _short(value: Any) -> str:
    """A setting as the message shows it: a string (a path, a name) whole, since its end is often what differs
    (`.../seed0_...` vs `.../seed1_...`); a longer list or mapping cut to 60 characters."""
    if isinstance(value, str):
        return value
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def setting_changes(recorded: dict[str, Any], current: dict[str, Any], keys: tuple[str, ...] | None = None,
                    allowed: tuple[str, ...] = (), classes: dict[str, type] | None = None) -> list[str]:
    """`key: recorded -> current` for each setting that differs (restricted to top-level `keys` if given), except
    those under an `allowed` key (a dotted key or a prefix of one, e.g. `data.init_args.rays_per_batch` or
    `model.optimizer`; `data.init_args.X` and `data.X` both name the data module's argument X), and, with `classes`
    (see `setting_default`), a setting the run did not record whose value is the current code's default: an option
    added to the code since the run was trained, left as it is (a new option's default keeps the old behaviour)."""
    if keys is not None:
        recorded = {k: v for k, v in recorded.items() if k in keys}
        current = {k: v for k, v in current.items() if k in keys}
    old, new = _flatten(recorded), _flatten(current)
    allowed = tuple(a.replace("data.init_args.", "data.").replace("model.init_args.", "model.") for a in allowed)
    changes = []
    for key in sorted(set(old) | set(new)):
        if old.get(key, "(unset)") == new.get(key, "(unset)"):
            continue
        if any(key == a or key.startswith(a + ".") for a in allowed):
            continue
        if key not in old and classes is not None and new[key] == _plain(setting_default(current, key, classes)):
            continue
        changes.append(f"{key}: {_short(old.get(key, '(unset)'))} -> {_short(new.get(key, '(unset)'))}")
    return changes


def scene_moved(recorded: dict[str, Any], current: dict[str, Any]) -> tuple[dict, dict, str | None]:
    """(recorded, current) as `setting_changes` compares them, and the folder the run's scene was read from where it
    is now elsewhere (else None). A scene is compared by its content: where both settings have its `scene_digest`
    and it is the same, the folder it is read from (`scene.scene`) is not compared (the scene was moved or copied).
    A run recorded before the digest (no `scene_digest`) compares the folder, as it did."""
    if DIGEST_KEY not in recorded:
        return recorded, {k: v for k, v in current.items() if k != DIGEST_KEY}, None
    old, new = recorded.get("scene"), current.get("scene")
    if recorded[DIGEST_KEY] != current.get(DIGEST_KEY) or not isinstance(old, dict) or not isinstance(new, dict):
        return recorded, current, None
    folder = old.get("scene")
    if folder == new.get("scene"):
        return recorded, current, None
    return {**recorded, "scene": {**old, "scene": new.get("scene")}}, current, folder


def check_run_settings(subcommand: str, checkpoint_path: Path, checkpoint: dict, current: dict[str, Any],
                       allowed: tuple[str, ...], classes: dict[str, type]) -> None:
    """A `fit` from `checkpoint` (a resume) continues its run: its data and model settings `current` must be those
    the checkpoint recorded; a `test` must score the scene and train views it trained on (`TEST_KEYS`). Differences
    in `allowed` (`--allow_changes`) pass (`setting_changes`); a scene moved or copied to another folder is the same
    scene (`scene_moved`), said in one line on stderr.

    Raises:
        CheckpointError: the settings differ; the line lists each difference, `key: recorded -> current`.
    """
    recorded = recorded_settings(checkpoint)
    if recorded is None:
        return  # written before runs recorded their settings
    recorded, current, moved_from = scene_moved(recorded, current)
    keys = TEST_KEYS if subcommand == "test" else None
    changes = setting_changes(recorded, current, keys, allowed, classes)
    what = "resume" if subcommand == "fit" else "test"
    if changes:
        listed = "; ".join(changes)
        if any(change.startswith(DIGEST_KEY + ":") for change in changes):
            listed += " (the scene's image names or poses are not those the run trained on)"
        raise CheckpointError(
            f"this {what} differs from the run of checkpoint {describe_checkpoint(checkpoint_path, checkpoint)} in "
            f"{listed}; use the run's settings (its config.yaml), start a new run in another folder, or accept the "
            f"change with --allow_changes [{', '.join(change.split(':')[0] for change in changes)}]"
        )
    if moved_from is not None and rank_zero_only.rank == 0:
        print(f"simplenerf: scene folder moved: {moved_from} -> {current['scene']['scene']} (the same image names and "
              f"poses); {'resuming' if subcommand == 'fit' else 'testing'} the run there", file=sys.stderr, flush=True)


def rng_state() -> dict[str, Any]:
    """Lightning's collection of the global random states, with numpy's key array as a tensor: checkpoints are
    loaded with `weights_only`, which refuses numpy arrays."""
    states = _collect_rng_states()
    if "numpy" in states:
        kind, keys, pos, has_gauss, cached = states["numpy"]
        states["numpy"] = (kind, torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss), float(cached))
    return states


def set_rng_state(states: dict[str, Any]) -> None:
    """Sets the states `rng_state` returned."""
    states = dict(states)
    if "numpy" in states:
        kind, keys, pos, has_gauss, cached = states["numpy"]
        states["numpy"] = (kind, np.asarray(keys, dtype=np.int64).astype(np.uint32), pos, has_gauss, cached)
    _set_rng_states(states)


def recorded_settings(checkpoint: dict) -> dict[str, Any] | None:
    """The run settings a checkpoint was trained with (None: written before they were recorded), with moved class
    paths read as the current ones."""
    record = checkpoint.get(RECORD_KEY)
    return current_class_paths(record.get("settings")) if isinstance(record, dict) else None


class RunRecord(L.Callback):
    """Writes the random state and the run's settings into every checkpoint, and sets the random state again when a
    fit resumes (module docstring). A default callback of every run (`cli.trainer_defaults`)."""

    def __init__(self) -> None:
        self.settings: dict[str, Any] | None = None
        """The run's settings (`run_settings`), set by the CLI before a fit."""
        self._rng: dict[str, Any] | None = None
        self._resumed_rng: dict[str, Any] | None = None

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        # Taken here, before the checkpoint callbacks (which Lightning calls last) write this step's checkpoint:
        # the state the next step starts from.
        self._rng = rng_state()

    def on_validation_end(self, trainer, pl_module) -> None:
        # Validation inside fit must not move the training's random stream (its data loader alone draws a seed from
        # it): the next step starts from the state the last one left, as after a resume from a checkpoint written
        # before the validation.
        if trainer.state.fn == "fit" and self._rng is not None:
            set_rng_state(self._rng)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint[RECORD_KEY] = {"settings": self.settings, "rng": self._rng or rng_state()}

    def on_load_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        record = checkpoint.get(RECORD_KEY)
        self._resumed_rng = record.get("rng") if isinstance(record, dict) else None

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        # Set at the first step, after everything between restore and training (the data loader's own seed draw).
        if self._resumed_rng is not None:
            set_rng_state(self._resumed_rng)
            self._resumed_rng = None


def describe_checkpoint(path: str | Path, checkpoint: dict) -> str:
    return f"{path} (step {int(checkpoint.get('global_step', 0))})"
