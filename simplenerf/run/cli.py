"""The LightningCLI of `python -m simplenerf {fit,validate,test,predict} --config ...`, with the project's defaults;
`make_cli` builds it for the Lightning verbs (`lightning_main`, dispatched by `simplenerf.commands`), the verbs that
read a run and the sweep's jobs.

Defaults every run gets: W&B logging (offline without credentials), progress (a bar in a terminal, a plain line
every N steps in a log file: `--progress.*`), rays/s, learning-rate logging, checkpoints under
`<trainer.default_root_dir>/checkpoints` (resume with `--ckpt_path last`), a stop on a NaN/inf loss, the validation
renders (`--val_renders.*`), the evaluation callback (`--evaluation.*`) that writes test metrics and renders, and an
optional video at the end of training (`--video.frames N`); `--viewer true`: the web viewer (`simplenerf.viewer`).

A run is trusted before it starts: inputs (data, LPIPS weights, the checkpoint and whether it fits the model, the
run folder; `simplenerf.run.checks`) are checked first and a problem stops the command with one `simplenerf: error:`
line, exit status 2 and nothing created (`simplenerf.run.console`: parser errors too, with a hint). `fit` refuses a run
folder that already has checkpoints unless it resumes (`--ckpt_path last`) or is told `--overwrite true`;
`<run>/config.yaml` records how the run was trained (`test` saves its own config beside its results).
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import Any, NoReturn

from jsonargparse import lazy_instance
from jsonargparse.typing import restricted_number_type
from lightning.pytorch import LightningDataModule, Trainer
from lightning.pytorch.cli import LightningArgumentParser, LightningCLI, SaveConfigCallback
from lightning.pytorch.utilities import rank_zero_only

from simplenerf.data.scene import SceneDataModule
from simplenerf.errors import DataError, SimpleNeRFError, Stopped, TrainingDiverged, absent
from simplenerf.evaluation.evaluator import Evaluator
from simplenerf.method.module import SimpleNeRF
from simplenerf.metrics.lpips import LPIPSWeightsNotFound
from simplenerf.model.fields import RadianceField
from simplenerf.run import hardware, signals
from simplenerf.run.callbacks import (
    Checkpointing,
    LearningRates,
    ProgressLog,
    RaysPerSecond,
    StopOnNonFiniteLoss,
    TrainingProgressBar,
    TrainingVideo,
    ValidationRenders,
)
from simplenerf.run.checks import (
    check_checkpoint_fits,
    check_model_meets_data,
    check_optimisation,
    check_trainer_options,
    check_unseen_patches,
    check_writable,
    kept_checkpoints,
    preflight_inputs,
    preflight_outputs,
    prepare_fresh_fit,
    read_checkpoint,
    resolve_checkpoint,
)
from simplenerf.run.config_files import FIT_ONLY_KEYS, SUBCOMMAND_KEYS, check_config_files, without_subcommand_keys
from simplenerf.run.console import PROG, HeldLogs, parser_error_line
from simplenerf.run.lock import command_line, lock_run_folder, release_run_folder
from simplenerf.run.loggers import WandbLogger
from simplenerf.run.memory import reuse_freed_memory
from simplenerf.run.resume import RunRecord, check_run_settings, run_settings

DESCRIPTION = (
    "SimpleNeRF (SIGGRAPH Asia 2023): Neural Radiance Fields from 2 to 4 photos, regularised by simpler augmented "
    "models. fit trains a run (resume with --ckpt_path last), validate scores the validation view, test renders and "
    "scores every test frame into <run>/test, predict renders the test frames. Start from a config in configs/, "
    "e.g. `simplenerf fit --config configs/demo.yaml`; `simplenerf fit --help` lists every option."
)


Port = restricted_number_type("Port", int, [(">=", 0), ("<=", 65535)])  # a TCP port (0: any free one)


class OneLineErrorParser(LightningArgumentParser):
    """The CLI's parser: a bad option or config ends with the error line first (`simplenerf: error: ...`), then at
    most one hint line, and exit status 2, instead of the full usage followed by nested causes."""

    def error(self, message: str, ex: Exception | None = None) -> NoReturn:
        if not self.exit_on_error:
            super().error(message, ex)
        parser = getattr(ex, "subcommand_parser", None) or self  # jsonargparse sets it on a subcommand's errors only
        line, hint = parser_error_line(message, parser)
        sys.stderr.write(f"{PROG}: error: {line}\n{hint}\n")
        sys.exit(2)


class RunConfig(SaveConfigCallback):
    """`fit` saves its config as `<run>/config.yaml`, the record of how the run was trained. Other subcommands leave
    that file alone and hand their config to the Evaluator, which keeps it beside their results
    (`<run>/test/config.yaml`)."""

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage == "fit":
            super().setup(trainer, pl_module, stage)
            return
        text = self.parser.dump(self.config, skip_none=False)
        for callback in trainer.callbacks:
            if isinstance(callback, Evaluator):
                callback.run_config = text


class SimpleNeRFCLI(LightningCLI):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # Lightning's info lines (seed, devices) appear once the inputs pass: a bad input prints its error line alone.
        self._held_logs = HeldLogs()
        try:
            super().__init__(*args, **kwargs)
        except BaseException:
            self._held_logs.release(emit=False)
            raise
        self._held_logs.release()

    def init_parser(self, **kwargs: Any) -> LightningArgumentParser:
        """Every parser (the main one and each subcommand's) without option abbreviations: `--trainer.max_step 5`
        is an unknown option (with the hint of the full name), not a silent `--trainer.max_steps`."""
        kwargs.setdefault("allow_abbrev", False)
        return super().init_parser(**kwargs)

    def parse_arguments(self, parser: LightningArgumentParser, args: Any) -> None:
        """As Lightning's, without its warning against giving `args` while sys.argv holds arguments: `make_cli`
        always passes the arguments itself (those of sys.argv, or a verb's or a test's)."""
        self.config = parser.parse_args(args)

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_lightning_class_args(Checkpointing, "checkpoint")
        parser.add_lightning_class_args(Evaluator, "evaluation")
        parser.add_lightning_class_args(ValidationRenders, "val_renders")
        parser.add_lightning_class_args(ProgressLog, "progress")
        parser.add_lightning_class_args(TrainingVideo, "video")
        parser.link_arguments(
            "trainer.default_root_dir", "checkpoint.dirpath", compute_fn=lambda root: os.path.join(root, "checkpoints")
        )
        # One setting of one fact: the NDC near plane the data module builds rays with is the one the NeRF maps
        # samples back to metric depth with.
        parser.link_arguments("data.init_args.near", "model.nerf.init_args.near")

    def _prepare_subcommand_parser(self, klass: type, subcommand: str, **kwargs: Any) -> LightningArgumentParser:
        # The one private override left: no public hook of LightningCLI (add_arguments_to_parser, init_parser) is
        # told which subcommand's parser it builds, and these options belong to fit (and test) alone.
        parser = super()._prepare_subcommand_parser(klass, subcommand, **kwargs)
        if subcommand == "fit":
            parser.add_argument(
                "--overwrite", type=bool, default=False,
                help="Start afresh in a run folder that already has checkpoints, deleting them. Without it, fit "
                "refuses such a folder unless it resumes with --ckpt_path.",
            )
            parser.add_argument("--viewer", type=bool, default=False,
                                help="Open the web viewer of the run while it trains (docs/viewer.md).")
            parser.add_argument("--viewer_port", type=Port, default=8080,
                                help="The viewer's port, 0-65535 (0: any free one).")
        if subcommand in ("fit", "test"):
            parser.add_argument(
                "--allow_changes", type=list[str], default=[],
                help="Data or model settings (keys as the refusal lists them, e.g. [data.init_args.rays_per_batch]) "
                "that may differ from those the checkpoint was trained with. Without it, a resume (or a test) whose "
                "settings differ from the run's stops. Trainer settings (max_steps, ...) may always change.",
            )
        return parser

    def instantiate_trainer(self, **kwargs: Any) -> Trainer:
        """The trainer, its W&B logger writing into the run folder unless told another `save_dir`."""
        trainer = super().instantiate_trainer(**kwargs)
        for logger in trainer.loggers:
            if isinstance(logger, WandbLogger):
                logger.use_run_folder(trainer.default_root_dir)
        return trainer

    def checkpoint_folder(self) -> Path:
        callback = self.trainer.checkpoint_callback
        if callback is not None and callback.dirpath is not None:
            return Path(callback.dirpath)
        return Path(self.trainer.default_root_dir) / "checkpoints"

    def output_folders(self, subcommand: str) -> list[Path]:
        """The folders `subcommand` writes into (checked for writing once the inputs pass)."""
        folders = [Path(self.trainer.default_root_dir)]
        if subcommand == "fit":
            folders.append(self.checkpoint_folder())
        folders += [Path(logger.save_dir) for logger in self.trainer.loggers if logger.save_dir is not None]
        for callback in self.trainer.callbacks:
            if isinstance(callback, Evaluator) and callback.output_dir is not None:
                folders.append(Path(callback.output_dir).parent)
        return list(dict.fromkeys(folders))

    # LightningCLI's public hooks around a subcommand: `before_<subcommand>` runs first, then the CLI's method named
    # after the subcommand (in place of the trainer's) with the subcommand's arguments.
    def before_fit(self) -> None:
        self.prepare("fit")

    def before_validate(self) -> None:
        self.prepare("validate")

    def before_test(self) -> None:
        self.prepare("test")

    def before_predict(self) -> None:
        self.prepare("predict")

    def fit(self, **kwargs: Any) -> None:
        self.execute("fit", **kwargs)

    def validate(self, **kwargs: Any) -> None:
        self.execute("validate", **kwargs)

    def test(self, **kwargs: Any) -> None:
        self.execute("test", **kwargs)

    def predict(self, **kwargs: Any) -> None:
        self.execute("predict", **kwargs)

    def prepare(self, subcommand: str) -> None:
        """Everything checked before a logger or an output creates anything; the checkpoint resolved."""
        self._render_instead = False
        if subcommand == "fit" and self.config_init[subcommand].get("viewer"):  # a callback like the others
            from simplenerf.run.callbacks.viewer import TrainingViewer

            self.trainer.callbacks.append(TrainingViewer(port=self.config_init[subcommand]["viewer_port"]))
        # Bad input (a missing scene, missing LPIPS weights, a checkpoint that does not fit) stops here, before
        # loggers or outputs create anything: the data module and every callback that declares pre-flight checks
        # (`simplenerf.run.checks`: ChecksModel, ChecksInputs, ChecksOutputs) run them.
        check_trainer_options(self.trainer, self.model)
        data = self.datamodule if isinstance(self.datamodule, SceneDataModule) else None
        check_model_meets_data(self.model, data.n_views if data is not None else None, subcommand)
        try:
            preflight_inputs([self.datamodule, *self.trainer.callbacks], self.model, subcommand)
            # Without test frames (own photos) `test` renders instead of scoring (`execute`): nothing needs LPIPS.
            scores_frames = data is None or bool(data.scene.split.test)
            if scores_frames:
                for evaluator in (c for c in self.trainer.callbacks if isinstance(c, Evaluator)):
                    evaluator.check_scoring(subcommand)
        except LPIPSWeightsNotFound as e:
            # The advice must be one that works: lpips_weights takes a path, lpips turns the metric off.
            raise SimpleNeRFError(re.sub(r"\(e\.g\. `--evaluation\.lpips_weights none`\)",
                                         "with `--evaluation.lpips false`", str(e))) from None
        if subcommand == "fit":  # a value torch refuses (a negative lr) stops here, not inside Lightning
            model_config = self.config[subcommand].get("model")
            check_optimisation(self.model, model_config.as_dict() if hasattr(model_config, "as_dict") else None)
        if data is not None and subcommand == "fit":
            check_model_meets_data(self.model, len(data.train_views), subcommand)
            check_unseen_patches(self.model, self.trainer.callbacks, data.unseen_patches_per_batch)
            self.model.set_train_views(data.train_views)  # what the reliability masks reproject into
        config = self.config_init[subcommand]
        folder = self.checkpoint_folder()
        # One writer per run folder (under DDP, rank 0 for all), locked before anything in it is read, moved or
        # deleted: a second command into a busy folder stops here and changes nothing (docs/running.md).
        run_folder = Path(self.trainer.default_root_dir)
        if rank_zero_only.rank == 0:
            lock_run_folder(run_folder, command_line())
        try:
            given = config.get("ckpt_path")
            config["ckpt_path"] = resolve_checkpoint(subcommand, given, folder, self.model)
            self.check_settings(subcommand, config)
            if subcommand == "fit" and given is None:
                prepare_fresh_fit(folder, bool(config.get("overwrite", False)))
            check_writable(self.output_folders(subcommand))
            preflight_outputs(self.trainer.callbacks, self.trainer, subcommand)  # e.g. an earlier test/ in the way
        except BaseException:
            release_run_folder(run_folder)  # a folder this command created is removed again
            raise
        self._held_logs.release()
        device = self.trainer.strategy.root_device
        hardware.announce(self.trainer.precision, device)  # once: rank 0 prints it
        if subcommand == "fit" and rank_zero_only.rank == 0:
            mlp = any(isinstance(f, RadianceField) for f in (self.model.nerf.coarse, self.model.nerf.fine))
            if hint := hardware.cpu_budget_hint(device, mlp, self.trainer.max_steps):
                print(f"simplenerf: {hint}", file=sys.stderr, flush=True)
        signals.at_step_end = subcommand == "fit"  # a test frame can take minutes: test stops at once
        self._render_instead = subcommand == "test" and not scores_frames

    def execute(self, subcommand: str, **kwargs: Any) -> None:
        """The trainer's `subcommand` with its arguments, its stops (a diverged loss, a signal) as one line each."""
        folder = self.checkpoint_folder()
        if self._render_instead:
            from simplenerf.viz.export import render_without_test_frames

            out = Path(self.trainer.default_root_dir) / "test"
            written = render_without_test_frames(self.model, self.datamodule, kwargs.get("ckpt_path"), out)
            print(f"simplenerf: this split has no test frames (train frames {self.datamodule.scene.split.train}), so "
                  f"there are no metrics; wrote the train views' depth maps and point cloud and the spiral video: "
                  f"{', '.join(map(str, written))}", flush=True)
            return
        try:
            getattr(self.trainer, subcommand)(**kwargs)
        except TrainingDiverged as e:
            raise TrainingDiverged(f"{e}; {kept_checkpoints(folder)}") from None
        except (KeyboardInterrupt, SystemExit) as e:  # Lightning's SIGTERMException and its sys.exit(1) on Ctrl-C
            if signals.received is None:
                raise
            raise self.stopped(subcommand, folder, signals.received) from e

    def stopped(self, subcommand: str, folder: Path, signum: int) -> Stopped:
        """The one line of a run a signal stopped (`simplenerf.run.signals`)."""
        how = f"{subcommand} stopped by {signals.name(signum)}"
        if subcommand == "fit":
            return Stopped(f"{how} at step {self.trainer.global_step}; {kept_checkpoints(folder)}", signum)
        return Stopped(f"{how} before it finished: no results were written (earlier results are kept)", signum)

    def check_settings(self, subcommand: str, config: Any) -> None:
        """A resume continues the run it resumes, and `test` scores the scene and train views the checkpoint trained
        on (`resume.check_run_settings`). Records the settings for `fit`."""
        record = next((c for c in self.trainer.callbacks if isinstance(c, RunRecord)), None)
        current = run_settings(self.config[subcommand], self.datamodule)
        if record is not None and subcommand == "fit":
            record.settings = current
        ckpt = config.get("ckpt_path")
        if subcommand not in ("fit", "test") or ckpt is None or not Path(str(ckpt)).is_file():
            return
        classes = {"model": type(self.model), "data": type(self.datamodule)}
        check_run_settings(subcommand, Path(ckpt), read_checkpoint(Path(ckpt)), current,
                           tuple(config.get("allow_changes") or ()), classes)


def trainer_defaults() -> dict:
    """Every run's trainer settings. In a terminal a progress bar (counting steps, also after a resume); elsewhere
    (a log file) no bar, and `ProgressLog` prints plain lines instead."""
    terminal = sys.stdout.isatty()
    return {
        "default_root_dir": "runs/default",
        "max_steps": 100000,
        "logger": lazy_instance(WandbLogger),
        "callbacks": [*([TrainingProgressBar()] if terminal else []), RaysPerSecond(), LearningRates(),
                      StopOnNonFiniteLoss(), RunRecord()],
        "enable_progress_bar": terminal,
        "check_val_every_n_epoch": None,
        "val_check_interval": 5000,
        "num_sanity_val_steps": 0,
    }


def make_cli(args: list[str] | None = None, run: bool = True, cli_class: type[LightningCLI] = SimpleNeRFCLI):
    """The CLI on `args` (None: sys.argv). With run=False it only builds model, data module and trainer (for a verb
    that reads a run).

    Every entry point comes through here, so this is also where SIMPLENERF_MALLOC=reuse takes effect (keep freed
    host memory for reuse: fewer page faults, more memory; see `simplenerf.run.memory`), and where subnormal floats
    start to be flushed to zero (`hardware.flush_denormals`; SIMPLENERF_DENORMALS=keep: not).
    A fit's saved `<run>/config.yaml` can be passed back as --config: the fit's own arguments in it (`overwrite`;
    for a tool also `ckpt_path` and `weights_only`) are dropped where they do not apply.
    """
    reuse_freed_memory()
    hardware.flush_denormals()
    given = list(sys.argv[1:] if args is None else args)
    check_config_files(given)
    if not run:  # a tool: none of a subcommand's arguments apply
        drop = SUBCOMMAND_KEYS
    else:
        drop = {"fit": (), "test": FIT_ONLY_KEYS}.get(given[0] if given else "", (*FIT_ONLY_KEYS, "allow_changes"))
    return cli_class(
        SimpleNeRF,
        LightningDataModule,
        subclass_mode_data=True,
        trainer_defaults=trainer_defaults(),
        save_config_callback=RunConfig,
        save_config_kwargs={"overwrite": True},
        parser_class=OneLineErrorParser,
        parser_kwargs={"prog": PROG, "description": DESCRIPTION},
        seed_everything_default=0,
        auto_configure_optimizers=False,  # the optimiser is the model's (`model.optimizer`, `model.lr_scheduler`)
        run=run,
        args=without_subcommand_keys(given, drop),
    )


def load_for_tool(
    configs: list[str], overrides: list[str], stage: str = "test", ckpt: str | None = None, device: str = "cpu"
) -> LightningCLI:
    """What the verbs that read a run start from (`simplenerf render-video`, ...): the CLI of `configs` + `overrides`
    without a logger, its data module set up for `stage` and, with `ckpt`, the model's trained weights loaded (eval
    mode, on `device`)."""
    if ckpt is not None and not Path(ckpt).is_file():
        raise DataError(f"checkpoint {ckpt} {absent(ckpt, folder=False)}")
    cli = make_cli([*(a for c in configs for a in ("--config", c)), *overrides, "--trainer.logger", "false"], run=False)
    cli.datamodule.setup(stage)
    if ckpt is not None:
        checkpoint = read_checkpoint(Path(ckpt))
        check_checkpoint_fits(Path(ckpt), checkpoint, cli.model)
        cli.model.load_state_dict(checkpoint["state_dict"])
        cli.model.to(device).eval()
    return cli


def lightning_main(args: list[str]) -> None:
    """The Lightning verbs, `simplenerf {fit,validate,test,predict} ...` (`args` starts with the verb)."""
    make_cli(args)
