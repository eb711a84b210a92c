"""Checks a run passes before it starts, so that it can be trusted: the checkpoint it starts from (exists, loads, fits
the model), the run folder (writable; a fresh `fit` does not overwrite another run's checkpoints) and what the model
needs of the data. Each failure is a `SimpleNeRFError` the command line prints as one line.

The parts of a run declare their own pre-flight checks by a protocol (`ChecksModel`, `ChecksInputs`,
`ChecksOutputs`): the CLI runs those of the data module and of every callback (`preflight_inputs`,
`preflight_outputs`) before loggers or outputs create anything. A user's callback takes part by defining the method.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Protocol, runtime_checkable

import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_only

from simplenerf.errors import CheckpointError, DataError, RunFolderError, SimpleNeRFError, absent, unwritable
from simplenerf.method.module import SimpleNeRF


@runtime_checkable
class ChecksModel(Protocol):
    """A part of a run (e.g. a loss-weight schedule) that checks the model has what it works on."""

    def check_model(self, model: L.LightningModule) -> None: ...


@runtime_checkable
class ChecksInputs(Protocol):
    """A part of a run (the data module, the viewer) that reads and checks what `stage` needs (the scene, a free
    port) before anything is written. The evaluator's LPIPS weights are checked after it, by the CLI, only when the
    scene has test frames to score (`Evaluator.check_scoring`)."""

    def check_inputs(self, stage: str) -> None: ...


@runtime_checkable
class ChecksOutputs(Protocol):
    """A part of a run (the evaluator) that checks it can write its outputs (e.g. no earlier results in the way)."""

    def check_outputs(self, trainer: L.Trainer, stage: str) -> None: ...


def preflight_inputs(parts: list[object], model: L.LightningModule, stage: str) -> None:
    """Every part's model checks, then every part's input checks, in the order of `parts` (data module first)."""
    for part in parts:
        if isinstance(part, ChecksModel):
            part.check_model(model)
    for part in parts:
        if isinstance(part, ChecksInputs):
            part.check_inputs(stage)


def preflight_outputs(parts: list[object], trainer: L.Trainer, stage: str) -> None:
    """Every part's output checks (once the run folder is known to be writable)."""
    for part in parts:
        if isinstance(part, ChecksOutputs):
            part.check_outputs(trainer, stage)

SPECIAL_CHECKPOINTS = ("best", "hpc")  # Lightning's own meanings of --ckpt_path, passed through unchecked


def read_checkpoint(path: Path, mmap: bool = False) -> dict:
    """The checkpoint at `path` loaded on the CPU (`mmap`: its tensors memory-mapped, read only when used);
    CheckpointError naming the file if it is missing or unreadable."""
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} {absent(path, folder=False)}")
    try:
        checkpoint = torch.load(path, map_location="cpu", mmap=mmap, weights_only=False)
    except Exception as e:  # a truncated zip, a pickle of something else, an empty file: all unreadable
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"cannot read checkpoint {path} (truncated or not a checkpoint: {reason})") from None
    if not isinstance(checkpoint, dict) or "state_dict" not in checkpoint:
        raise CheckpointError(f"{path} is not a Lightning checkpoint (it has no state_dict)")
    return checkpoint


def check_checkpoint_fits(path: Path, checkpoint: dict, model: torch.nn.Module) -> None:
    """CheckpointError unless the checkpoint's weights have exactly the model's names and shapes."""
    theirs, ours = checkpoint["state_dict"], model.state_dict()
    problem = None
    for name, tensor in ours.items():
        if name not in theirs:
            problem = f"it has no {name}"
        elif tuple(theirs[name].shape) != tuple(tensor.shape):
            problem = f"{name} is {tuple(theirs[name].shape)} in it but {tuple(tensor.shape)} in the model"
        if problem:
            break
    if problem is None and (extra := sorted(set(theirs) - set(ours))):
        problem = f"it has {extra[0]}, which the model does not"
    if problem:
        raise CheckpointError(f"checkpoint {path} does not fit the model: {problem} (was it trained with another "
                              "config?)")


def usable_checkpoint(path: Path, model: torch.nn.Module) -> int:
    """Checks that `path` can be loaded into `model`; returns its global step."""
    checkpoint = read_checkpoint(path)
    check_checkpoint_fits(path, checkpoint, model)
    return int(checkpoint.get("global_step", 0))


def checkpoints_newest_first(folder: Path) -> list[Path]:
    """The `*.ckpt` files of `folder`: last.ckpt first, then the others from the newest (modification time)."""
    if not folder.is_dir():
        return []
    others = sorted((p for p in folder.glob("*.ckpt") if p.name != "last.ckpt"),
                    key=lambda p: (p.stat().st_mtime, p.name), reverse=True)
    last = folder / "last.ckpt"
    return [last, *others] if last.is_file() else others


def notice(text: str) -> None:
    """A line on stderr about a choice the checks made for the user (the processes of other ranks stay quiet)."""
    if rank_zero_only.rank == 0:
        print(f"simplenerf: {text}", file=sys.stderr, flush=True)


def resolve_checkpoint(stage: str, ckpt_path: str | None, folder: Path, model: torch.nn.Module) -> str | None:
    """The checkpoint `stage` starts from, checked: it exists, loads and fits `model`.

    `last` is `<folder>/last.ckpt`. validate/test/predict need a checkpoint. `fit --ckpt_path last` falls back to
    the checkpoint of `folder` with the highest step among those that load and fit when last.ckpt is missing,
    unreadable or does not fit (and says so), and trains from the start when `folder` has no checkpoint.
    """
    if ckpt_path in SPECIAL_CHECKPOINTS or (ckpt_path or "").startswith("registry"):
        return ckpt_path
    if ckpt_path is None:
        if stage == "fit":
            return None
        raise CheckpointError(f"{stage} needs trained weights: add --ckpt_path last (the run's {folder / 'last.ckpt'})"
                              " or --ckpt_path FILE")
    if ckpt_path != "last":
        usable_checkpoint(Path(ckpt_path), model)
        return ckpt_path
    last = folder / "last.ckpt"
    if stage != "fit":
        if not last.is_file():
            raise CheckpointError(f"no checkpoint to {stage}: {last} does not exist (train the run with fit first, "
                                  "or give --ckpt_path FILE)")
        usable_checkpoint(last, model)
        return str(last)
    candidates = checkpoints_newest_first(folder)
    if not candidates:
        notice(f"no checkpoint in {folder} to resume: training from the start")
        return None
    problems: list[CheckpointError] = []
    usable: list[tuple[int, Path]] = []
    for path in candidates:  # last.ckpt first: if it is usable, no other is read
        try:
            usable.append((usable_checkpoint(path, model), path))
        except CheckpointError as e:
            problems.append(e)
        if path == last and usable:
            return str(last)
    if not usable:
        raise CheckpointError(f"{problems[0]}; no other checkpoint in {folder} can be resumed either")
    step, path = max(usable, key=lambda item: item[0])
    why = str(problems[0]) if last.is_file() else f"{last} does not exist"
    notice(f"{why}; resuming from {path} (step {step}), the newest readable checkpoint, instead")
    return str(path)


def prepare_fresh_fit(folder: Path, overwrite: bool) -> None:
    """A fit without a checkpoint must not overwrite another run's checkpoints: RunFolderError if `folder` has some,
    unless `overwrite`, which deletes them (a fresh run does not mix its checkpoints with an earlier one's)."""
    existing = sorted(folder.glob("*.ckpt")) if folder.is_dir() else []
    if not existing:
        return
    if not overwrite:
        raise RunFolderError(
            f"{folder} already has checkpoints ({', '.join(p.name for p in existing[:3])}"
            f"{', ...' if len(existing) > 3 else ''}): resume that run with --ckpt_path last, choose another folder "
            "with --trainer.default_root_dir, or start afresh with --overwrite true"
        )
    for path in existing:
        path.unlink()
    notice(f"--overwrite: deleted the {len(existing)} checkpoints of the earlier run in {folder}")


def check_writable(folders: list[Path]) -> None:
    """Creates each folder and writes (then deletes) a file in it: RunFolderError naming the first that fails."""
    for folder in folders:
        if (reason := unwritable(folder)) is not None:
            raise RunFolderError(f"cannot write to the run folder {folder}: {reason}")


def check_model_meets_data(model: SimpleNeRF, n_train: int | None, stage: str) -> None:
    """What the model needs of the data at fit start: the reliability masks of the augmentations and of L_cfc
    reproject depth into another train view, so they need at least 2 train views (`n_train`; None: not known)."""
    if stage != "fit" or n_train is None:
        return
    parts = []
    if len(model.augmentations):
        parts.append("augmentations")
    if model.coarse_fine_mask is not None:
        parts.append("coarse_fine_mask")
    if parts and n_train < 2:
        raise DataError(
            f"{n_train} train view is too few for this model: its {' and '.join(parts)} compare depth across train "
            "views and need at least 2 (use n_views >= 2, or a model without them, e.g. configs/dsnerf.yaml)"
        )


def check_unseen_patches(model: SimpleNeRF, callbacks: list, per_batch: int) -> None:
    """DataError when a term that reads patches from unseen cameras (RegNeRF's depth smoothness) has a weight, or a
    schedule (a callback's `schedules`, `LossWeightSchedule`) gives it one, and the data serves none (`per_batch` 0):
    it would never be computed."""
    if per_batch:
        return
    schedules = [c for c in callbacks if hasattr(c, "zero_from")]  # LossWeightSchedule's rule for "0 from a step on"
    used = [name for name, term in model.terms.items() if "unseen" in term.reads and (
        term.weight != 0 or not all(s.zero_from(name, -1, 0.0) for s in schedules))]
    if used:
        raise DataError(f"the loss terms {', '.join(used)} read patches from unseen cameras, but the data serves none: "
                        "set --data.init_args.unseen_patches_per_batch (e.g. 4)")


# Trainer options Lightning applies only under automatic optimisation: SimpleNeRF optimises manually (one update per
# step, `SimpleNeRF.training_step`), so they would change nothing (or stop inside Lightning): refused up front.
MANUAL_OPTIMISATION_IGNORES = {"gradient_clip_val": None, "gradient_clip_algorithm": None, "accumulate_grad_batches": 1}


def check_trainer_options(trainer: L.Trainer, model: L.LightningModule) -> None:
    """SimpleNeRFError naming the first trainer option that the model's manual optimisation ignores, if set."""
    if getattr(model, "automatic_optimization", True):
        return
    values = {"gradient_clip_val": trainer.gradient_clip_val,
              "gradient_clip_algorithm": trainer.gradient_clip_algorithm,
              "accumulate_grad_batches": trainer.accumulate_grad_batches}
    for name, default in MANUAL_OPTIMISATION_IGNORES.items():
        value = getattr(values[name], "value", values[name])  # the clipping algorithm is an enum
        if value is not None and value != default:
            raise SimpleNeRFError(
                f"--trainer.{name} {value}: SimpleNeRF optimises manually (one update per step), which "
                f"Lightning's {name} does not apply to; leave it unset (a larger --data.init_args.rays_per_batch with "
                "--model.rays_per_backward accumulates gradients over a batch's parts)"
            )


def _described(config: dict | None, key: str, default: str) -> str:
    """`--model.<key> (<class>)`, the option a refusal names, with the class the config gives it."""
    node = (config or {}).get(key)
    class_path = node.get("class_path") if isinstance(node, dict) else None
    return f"--model.{key} ({class_path or default})"


def check_optimisation(model: SimpleNeRF, config: dict | None = None) -> None:
    """The parameter groups, optimiser and learning-rate schedule a fit builds (`SimpleNeRF.configure_optimizers`),
    built once here on the model's parameters: a value torch refuses (a negative learning rate, betas outside
    [0, 1), a decay rate <= 0, a group_lr naming no group) stops the fit before anything is written, with the option
    and torch's reason, instead of a traceback inside Lightning. `config` is the model's parsed config (a dict), for
    the class names."""
    from simplenerf.method.optim import ExponentialDecay, default_optimizer, parameter_groups

    for name, lr in model.group_lr.items():
        if not (isinstance(lr, (int, float)) and math.isfinite(lr) and lr >= 0):
            raise SimpleNeRFError(f"--model.group_lr: the learning rate of group {name!r} is {lr}; expected a number "
                                  ">= 0")
    try:
        groups = parameter_groups(model, model.group_lr)
    except ValueError as e:
        raise SimpleNeRFError(f"--model.group_lr: {e}") from None
    try:
        optimizer = (model.optimizer or default_optimizer)(groups)
    except (ValueError, TypeError) as e:
        raise SimpleNeRFError(f"{_described(config, 'optimizer', 'torch.optim.Adam')}: {e}") from None
    try:
        model.lr_scheduler(optimizer) if model.lr_scheduler is not None else ExponentialDecay(optimizer)
    except (ValueError, TypeError, ZeroDivisionError) as e:
        raise SimpleNeRFError(f"{_described(config, 'lr_scheduler', 'ExponentialDecay')}: {e}") from None


def kept_checkpoints(folder: Path) -> str:
    """Which checkpoint survives a stopped run, for its error line."""
    candidates = checkpoints_newest_first(folder)
    if not candidates:
        return "no checkpoint had been written yet"
    try:
        step = f", step {int(read_checkpoint(candidates[0]).get('global_step', 0))}"
    except CheckpointError:
        step = ""
    return f"the checkpoints written before it are kept (resume from {candidates[0]}{step})"
