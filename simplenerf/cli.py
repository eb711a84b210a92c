"""`python -m simplenerf {fit,validate,test,predict} --config ...`: LightningCLI with the project's defaults.

Defaults every run gets: W&B logging (offline without credentials), a rich progress bar with rays/s, learning-rate
logging, checkpoints under `<trainer.default_root_dir>/checkpoints` (resume with `--ckpt_path last`), the
validation renders (`--val_renders.*`: RGB, depth, accumulation and error map of the validation view at every
validation) and the evaluation callback (`--evaluation.*`) that writes test metrics and renders.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

import torch
from jsonargparse import lazy_instance
from lightning.pytorch import LightningDataModule
from lightning.pytorch.callbacks import RichProgressBar
from lightning.pytorch.cli import LightningCLI

from simplenerf.callbacks import Checkpointing, LearningRates, RaysPerSecond
from simplenerf.errors import DataError, SimpleNeRFError
from simplenerf.evaluation.evaluator import Evaluator
from simplenerf.evaluation.lpips import LPIPSWeightsNotFound
from simplenerf.loggers import WandbLogger
from simplenerf.memory import reuse_freed_memory
from simplenerf.module import SimpleNeRF
from simplenerf.viz.renders import ValidationRenders


class SimpleNeRFCLI(LightningCLI):
    def add_arguments_to_parser(self, parser) -> None:
        parser.add_lightning_class_args(Checkpointing, "checkpoint")
        parser.add_lightning_class_args(Evaluator, "evaluation")
        parser.add_lightning_class_args(ValidationRenders, "val_renders")
        parser.link_arguments(
            "trainer.default_root_dir", "checkpoint.dirpath", compute_fn=lambda root: os.path.join(root, "checkpoints")
        )


    def _run_subcommand(self, subcommand: str) -> None:
        # Bad input (a missing scene, missing LPIPS weights) stops here, before loggers or outputs are created.
        if hasattr(self.datamodule, "check_inputs"):
            self.datamodule.check_inputs(subcommand)
        for callback in self.trainer.callbacks:
            if hasattr(callback, "check_inputs"):
                callback.check_inputs(subcommand)
        super()._run_subcommand(subcommand)


def trainer_defaults() -> dict:
    return {
        "default_root_dir": "runs/default",
        "max_steps": 100000,
        "logger": lazy_instance(WandbLogger),
        "callbacks": [RichProgressBar(), RaysPerSecond(), LearningRates()],
        "check_val_every_n_epoch": None,
        "val_check_interval": 5000,
        "num_sanity_val_steps": 0,
    }


def make_cli(args: list[str] | None = None, run: bool = True, cli_class: type[LightningCLI] = SimpleNeRFCLI):
    """The CLI on `args` (None: sys.argv). With run=False it only builds model, data module and trainer (tools).

    Every entry point comes through here, so this is also where SIMPLENERF_MALLOC=reuse takes effect (keep freed
    host memory for reuse: fewer page faults, more memory; see `simplenerf.memory`).
    """
    reuse_freed_memory()
    return cli_class(
        SimpleNeRF,
        LightningDataModule,
        subclass_mode_data=True,
        trainer_defaults=trainer_defaults(),
        save_config_kwargs={"overwrite": True},
        run=run,
        args=args,
    )


def load_for_tool(
    configs: list[str], overrides: list[str], stage: str = "test", ckpt: str | None = None, device: str = "cpu"
) -> LightningCLI:
    """What the tools in tools/ start from: the CLI of `configs` + `overrides` without a logger, its data module set
    up for `stage` and, with `ckpt`, the model's trained weights loaded (eval mode, on `device`)."""
    if ckpt is not None and not Path(ckpt).is_file():
        raise DataError(f"checkpoint {ckpt} does not exist")
    cli = make_cli([*(a for c in configs for a in ("--config", c)), *overrides, "--trainer.logger", "false"], run=False)
    cli.datamodule.setup(stage)
    if ckpt is not None:
        cli.model.load_state_dict(torch.load(ckpt, map_location="cpu", weights_only=False)["state_dict"])
        cli.model.to(device).eval()
    return cli


def run_tool(main_function: Callable[[], None], name: str) -> None:
    """Runs a tool's main; bad input ends with one `<name>: error:` line and exit status 2, as in `main`."""
    try:
        main_function()
    except (SimpleNeRFError, LPIPSWeightsNotFound) as e:
        print(f"{name}: error: {e}", file=sys.stderr)
        sys.exit(2)


def split_overrides(argv: list[str]) -> tuple[list[str], list[str]]:
    """A tool's own arguments and, after `--`, the overrides it passes to the CLI."""
    if "--" not in argv:
        return argv, []
    i = argv.index("--")
    return argv[:i], argv[i + 1 :]


def main(args: list[str] | None = None) -> None:
    """Entry point; bad input ends with one `error:` line and exit status 2 instead of a traceback."""
    run_tool(lambda: make_cli(args), "simplenerf")
