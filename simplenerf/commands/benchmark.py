r"""Seconds per training step and peak memory of a config on this machine: times N training iterations after W
warm-up iterations and prints ONE JSON line (benchmarks.speed.training_step), e.g.

    simplenerf benchmark --config configs/llff.yaml --steps 3 --warmup 2 --rays 256 --precision 32-true \
        --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern --data.init_args.sparse_rays_per_batch 256

The CLI's options (`simplenerf fit`'s) are overrides of the config. `--tf32` allows TF32 matrix products in fp32
(CUDA). The JSON holds s/it (median, min, max, all), rays/s, field evaluations/s, peak RSS and peak CUDA
memory, CPU user/system time and page faults per iteration, the losses computed, and the machine (CPU model and
capability: AVX2, AVX-512, AVX-512 BF16 or AMX; the GPU model). Before the first step it names the CPU and warns when
the precision has no fast kernels on it (`simplenerf.run.hardware`). `--weights CKPT` times
from a checkpoint's weights (a step late in a fit) instead of the initialisation. The config's warm-up schedule
is not applied: every loss is computed at its configured weight (the cost of a step after the warm-up). Run
`simplenerf sparse-depth` with the same arguments first, so that SfM is not in the measured process. One measurement
per process: peak memory is per process. More measurements (rendering, a profile, the release side by side):
benchmarks/ in the repository.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.errors import SimpleNeRFError


def speed():
    """`benchmarks.speed.training_step`, the measurement: it lives in the repository's benchmarks/, not in the
    installed package, and is found beside the package (a checkout, or an editable install) when the working folder
    is elsewhere. The package's one import of benchmarks/ (tests/test_layout.py allows this one only)."""
    try:
        return importlib.import_module("benchmarks.speed.training_step")
    except ModuleNotFoundError as e:
        if e.name not in ("benchmarks", "benchmarks.speed", "benchmarks.speed.training_step"):
            raise
    root = Path(__file__).resolve().parents[2]
    if not (root / "benchmarks" / "speed" / "training_step.py").is_file():
        raise SimpleNeRFError(f"benchmark: the repository's benchmarks/speed/training_step.py is not beside the "
                              f"package ({root}); run simplenerf benchmark from a checkout of the repository")
    sys.path.insert(0, str(root))
    return importlib.import_module("benchmarks.speed.training_step")


def measurement_parser(doc: str | None, prog: str | None = None) -> CommandParser:
    """The options every measurement shares: configs, precision, TF32, accelerator, a label. `prog`: a script of
    benchmarks/ (default: `simplenerf benchmark`)."""
    parser = CommandParser("benchmark", doc, prog)
    parser.add_argument("--config", action="append", required=True, help="a config file (repeat to stack)")
    parser.add_argument("--precision", default="32-true", help="Lightning precision: 32-true, bf16-mixed, 16-mixed")
    parser.add_argument("--tf32", action="store_true", help="TF32 matrix products for fp32 (CUDA, Ampere and newer)")
    parser.add_argument("--accelerator", default="auto", help="Lightning accelerator (auto, cpu, cuda)")
    parser.add_argument("--label", default=None, help="free text copied into the JSON (e.g. a variant name)")
    return parser


def build(args: argparse.Namespace, overrides: list[str]):
    """The CLI (model, data module) of the parsed measurement `args` and the CLI `overrides`, seed 0 first (a run's
    rays are reproducible; an override still wins), without a logger."""
    from simplenerf.run.cli import make_cli

    speed().set_tf32(args.tf32)
    configs = [a for c in args.config for a in ("--config", c)]
    return make_cli(["--seed_everything", "0", *configs, "--trainer.logger", "false", *overrides], run=False)


def record_header(kind: str, args: argparse.Namespace, overrides: list[str]) -> dict:
    """What every JSON line starts with: the measurement, its settings, the machine (CPU model and capability, the GPU
    model where there is one: `simplenerf.run.hardware`), its threads, torch, the commit."""
    from simplenerf.evaluation.evaluator import git_commit
    from simplenerf.run.hardware import machine_record

    return {
        "benchmark": kind,
        "label": args.label,
        "config": args.config if len(args.config) > 1 else args.config[0],
        "overrides": overrides,
        "precision": args.precision,
        "tf32": args.tf32,
        **machine_record(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "commit": git_commit(),
    }


def emit(record: dict) -> None:
    """One JSON line on stdout (everything else a run prints goes to stderr)."""
    print(json.dumps(record), flush=True)


STEPS = {"steps": (3, "timed iterations")}  # `simplenerf benchmark`'s own option


def training_parser(doc: str | None, extra: dict[str, tuple[int, str]], prog: str | None = None) -> CommandParser:
    """The parser of a training measurement: `measurement_parser`'s options, `--warmup`, `--rays` and `extra` (name
    -> (default, help))."""
    parser = measurement_parser(doc, prog)
    for name, (default, text) in {"warmup": (2, "untimed iterations first"), **extra}.items():
        parser.add_argument(f"--{name}", type=int, default=default, help=text)
    parser.add_argument("--rays", type=int, help="random rays per iteration (overrides the config's)")
    parser.add_argument("--weights", default=None,
                        help="a checkpoint of the config's model to time from: the cost of a step late in a fit, "
                             "whose fields no longer have their initial values (default: the initialisation)")
    return parser


def build_parser() -> CommandParser:
    """`simplenerf benchmark`'s parser."""
    return training_parser(__doc__, STEPS)


def training_args(argv: Sequence[str], doc: str | None, extra: dict[str, tuple[int, str]], prog: str | None = None):
    """The arguments of a training measurement (`training_parser`'s), its CLI overrides and the CLI they build."""
    own, overrides = split_overrides(argv)
    args = training_parser(doc, extra, prog).parse_args(own)
    if args.rays:
        overrides = [*overrides, "--data.init_args.rays_per_batch", str(args.rays)]
    with stdout_to_stderr():
        cli = build(args, overrides)
        if args.weights:
            load_weights(cli.model, Path(args.weights))
        warn_zero_weights(cli.model)
    return args, overrides, cli


def load_weights(model: nn.Module, path: Path) -> None:
    """The model weights of the checkpoint at `path` loaded into `model` (not its optimiser state: a timed step
    starts Adam afresh); CheckpointError naming the file when it is unreadable or was trained with another config."""
    from simplenerf.run.checks import check_checkpoint_fits, read_checkpoint

    checkpoint = read_checkpoint(path)
    check_checkpoint_fits(path, checkpoint, model)
    model.load_state_dict(checkpoint["state_dict"])


def main(argv: Sequence[str]) -> dict:
    args, overrides, cli = training_args(argv, __doc__, STEPS)
    with stdout_to_stderr():
        result = speed().time_training(cli.model, cli.datamodule, args.steps, args.warmup, args.precision,
                                       args.accelerator)
    record = {**record_header("train_step", args, overrides), "steps": args.steps, "warmup": args.warmup, **result}
    emit(record)
    return record


def warn_zero_weights(model: nn.Module) -> None:
    """Says on stderr which losses are off (weight 0): they are skipped, so the step is cheaper than the paper's."""
    zero = sorted(name for name, term in model.terms.items() if not term.weight)
    if zero:
        print(f"benchmark: note: losses with weight 0 are skipped: {zero}", file=sys.stderr)


class stdout_to_stderr:
    """Lightning and the data module print progress to stdout; keep stdout for the one JSON line."""

    def __enter__(self) -> None:
        self._saved = sys.stdout
        sys.stdout = sys.stderr

    def __exit__(self, *exc) -> None:
        sys.stdout = self._saved
