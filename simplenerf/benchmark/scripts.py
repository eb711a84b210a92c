"""The command lines of benchmarks/*.py: parse `--config ... -- OVERRIDES`, measure, print one JSON line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from torch import nn

from simplenerf.benchmark.measure import set_tf32, time_rendering, time_training
from simplenerf.benchmark.profile import profile_table, profile_training


def _split(argv: list[str]) -> tuple[list[str], list[str]]:
    if "--" not in argv:
        return argv, []
    i = argv.index("--")
    return argv[:i], argv[i + 1 :]


def _common_parser(description: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", action="append", required=True, help="a config file (repeat to stack)")
    parser.add_argument("--precision", default="32-true", help="Lightning precision: 32-true, bf16-mixed, 16-mixed")
    parser.add_argument("--tf32", action="store_true", help="TF32 matrix products for fp32 (CUDA, Ampere and newer)")
    parser.add_argument("--accelerator", default="auto", help="Lightning accelerator (auto, cpu, cuda)")
    parser.add_argument("--label", default=None, help="free text copied into the JSON (e.g. a variant name)")
    return parser


def _build(args: argparse.Namespace, overrides: list[str]):
    from simplenerf.cli import make_cli

    set_tf32(args.tf32)
    configs = [a for c in args.config for a in ("--config", c)]
    # Fixed seed first so that a run's rays are reproducible; an override after `--` still wins. The CLI sees only
    # these arguments (LightningCLI warns when sys.argv holds others).
    argv, sys.argv = sys.argv, sys.argv[:1]
    try:
        return make_cli(["--seed_everything", "0", *configs, "--trainer.logger", "false", *overrides], run=False)
    finally:
        sys.argv = argv


def _header(kind: str, args: argparse.Namespace, overrides: list[str]) -> dict:
    from simplenerf.evaluation.evaluator import git_commit

    return {
        "benchmark": kind,
        "label": args.label,
        "config": args.config if len(args.config) > 1 else args.config[0],
        "overrides": overrides,
        "precision": args.precision,
        "tf32": args.tf32,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "commit": git_commit(),
    }


def _emit(record: dict) -> None:
    """One JSON line on stdout (everything else a run prints goes to stderr)."""
    print(json.dumps(record), flush=True)


def _training_args(argv: list[str] | None, description: str, extra: dict[str, tuple[int, str]]):
    """The arguments of a training measurement (`--warmup` and `extra`: name -> (default, help)), its CLI overrides
    and the model + data module they build."""
    own, overrides = _split(list(sys.argv[1:] if argv is None else argv))
    parser = _common_parser(description)
    for name, (default, text) in {"warmup": (2, "untimed iterations first"), **extra}.items():
        parser.add_argument(f"--{name}", type=int, default=default, help=text)
    args = parser.parse_args(own)
    with _stdout_to_stderr():
        cli = _build(args, overrides)
        warn_zero_weights(cli.model)
    return args, overrides, cli


def train_step_main(argv: list[str] | None = None, description: str | None = None) -> dict:
    """`benchmarks/train_step.py`: times training iterations of a config, prints one JSON line."""
    args, overrides, cli = _training_args(argv, description or train_step_main.__doc__,
                                          {"steps": (3, "timed iterations")})
    with _stdout_to_stderr():
        result = time_training(cli.model, cli.datamodule, args.steps, args.warmup, args.precision, args.accelerator)
    record = {**_header("train_step", args, overrides), "steps": args.steps, "warmup": args.warmup, **result}
    _emit(record)
    return record


def render_main(argv: list[str] | None = None, description: str | None = None) -> dict:
    """`benchmarks/render.py`: times full-frame rendering of test views, prints one JSON line."""
    own, overrides = _split(list(sys.argv[1:] if argv is None else argv))
    parser = _common_parser(description or render_main.__doc__)
    parser.add_argument("--ckpt", default=None, help="trained weights (default: initial weights, same cost)")
    parser.add_argument("--frames", type=int, default=1, help="timed frames (test views in order)")
    parser.add_argument("--warmup", type=int, default=0, help="untimed frames first")
    parser.add_argument("--rows", type=int, default=None, help="render only the top ROWS rows (a quick rays/s check)")
    args = parser.parse_args(own)
    if args.ckpt is not None and not Path(args.ckpt).is_file():
        parser.error(f"checkpoint {args.ckpt} does not exist")
    with _stdout_to_stderr():
        cli = _build(args, overrides)
        result = time_rendering(cli.model, cli.datamodule, args.frames, args.warmup, args.precision, args.ckpt,
                                args.accelerator, rows=args.rows)
    record = {**_header("render", args, overrides), "ckpt": args.ckpt, "warmup": args.warmup, "rows": args.rows,
              **result}
    _emit(record)
    return record


def profile_main(argv: list[str] | None = None, description: str | None = None) -> dict:
    """`benchmarks/profile_step.py`: profiles one training iteration after warm-up; prints a markdown table of the
    top operators by self CPU time, then one JSON line."""
    args, overrides, cli = _training_args(argv, description or profile_main.__doc__, {"top": (25, "operators to list")})
    with _stdout_to_stderr():
        result = profile_training(cli.model, cli.datamodule, args.warmup, args.precision, args.top, args.accelerator)
    record = {**_header("profile", args, overrides), "warmup": args.warmup, **result}
    print(f"iteration {record['iteration_s']:.2f} s wall: user {record['user_s']:.2f} s, "
          f"system {record['sys_s']:.2f} s, {record['minor_faults']} minor page faults, {record['threads']} threads, "
          f"peak RSS {record['peak_rss_gib']:.2f} GiB")
    print(f"matrix products (aten::mm/addmm/bmm) {record['matmul_s']:.2f} s at {record['matmul_gflop_per_s']:.0f} "
          f"GFLOP/s ({record['matmul_gflop']:.0f} GFLOP), all other operators {record['other_ops_s']:.2f} s (self CPU "
          f"time)\n")
    print(profile_table(record))
    _emit(record)
    return record


def warn_zero_weights(model: nn.Module) -> None:
    """Says on stderr which losses are off (weight 0): they are skipped, so the step is cheaper than the paper's."""
    zero = sorted(name for name, term in model.terms.items() if not term.weight)
    if zero:
        print(f"benchmark: note: losses with weight 0 are skipped: {zero}", file=sys.stderr)


class _stdout_to_stderr:
    """Lightning and the data module print progress to stdout; keep stdout for the one JSON line."""

    def __enter__(self) -> None:
        self._saved = sys.stdout
        sys.stdout = sys.stderr

    def __exit__(self, *exc) -> None:
        sys.stdout = self._saved


# ---------------------------------------------------------------------------------------------------------------------
# Side by side with the authors' release (../shared/tools/official_timing/driver.py --json_out files)


