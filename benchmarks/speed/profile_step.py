"""Profiles one training iteration after W warm-up iterations (torch.profiler, CPU; + CUDA on a GPU): prints a
markdown table of the top operators by self CPU time, then ONE JSON line with the iteration's wall, user and system
time and minor page faults. E.g. the release's variant B on one thread:

    OMP_NUM_THREADS=1 python -m benchmarks.speed.profile_step --config configs/llff.yaml --warmup 2 \
        -- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern \
           --data.init_args.rays_per_batch 256 --data.init_args.sparse_rays_per_batch 256

The profiler adds overhead per operator: compare shares within one profile, and take s/it from `simplenerf benchmark`.
torch.profiler's "CPU time" is the wall-clock time of each operator on the CPU side, so on a shared machine it
includes waiting for a core: the JSON's `cpu_over_wall` (user + system time / wall time) says how much of the
iteration the process actually ran.
"""

from __future__ import annotations

import sys

import lightning as L
import torch

from benchmarks.speed.training_step import StepTimer, measuring_trainer, peak_rss_gib
from simplenerf.commands.benchmark import emit, record_header, stdout_to_stderr, training_args


def profile_training(
    model: L.LightningModule,
    datamodule: L.LightningDataModule,
    warmup: int,
    precision: str,
    top: int = 25,
    accelerator: str = "auto",
) -> dict:
    """Runs `warmup` iterations, then one under `torch.profiler`; returns the iteration's wall, user and system time
    and page faults, and the `top` operators by self CPU time (each: name, calls, self and total CPU seconds).

    The matrix products' FLOPs are counted in the last warm-up iteration (`FlopCounterMode`; an iteration computes the
    same products every time), not by the profiler: its `with_flops` keeps every operator's inputs alive until the
    profile ends (at 2048 + 2048 rays: 19.7 GiB and 3.6 M page faults instead of 7.8 GiB and 0.17 M)."""
    from torch.profiler import ProfilerActivity, profile
    from torch.utils.flop_counter import FlopCounterMode

    class Profiled(StepTimer):
        def __init__(self) -> None:
            super().__init__()
            self.profiler: profile | None = None
            self.counter: FlopCounterMode | None = None

        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
            if batch_idx == warmup - 1:
                self.counter = FlopCounterMode(display=False)
                self.counter.__enter__()
            if batch_idx == warmup:
                activities = [ProfilerActivity.CPU]
                if pl_module.device.type == "cuda":
                    activities.append(ProfilerActivity.CUDA)
                self.profiler = profile(activities=activities)
                self.profiler.__enter__()
            super().on_train_batch_start(trainer, pl_module, batch, batch_idx)

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
            super().on_train_batch_end(trainer, pl_module, outputs, batch, batch_idx)
            if batch_idx == warmup - 1 and self.counter is not None:
                self.counter.__exit__(None, None, None)
            if batch_idx == warmup and self.profiler is not None:
                self.profiler.__exit__(None, None, None)

    timer = Profiled()
    trainer = measuring_trainer(precision, accelerator, 1, max_steps=warmup + 1, callbacks=[timer])
    datamodule.setup("fit")
    model.set_train_views(datamodule.train_views)
    trainer.fit(model, datamodule)
    assert timer.profiler is not None, "the profiled iteration did not run"
    events = timer.profiler.key_averages()
    total_self = sum(e.self_cpu_time_total for e in events)
    flop = 0
    if timer.counter is not None:
        counts = timer.counter.get_flop_counts().get("Global", {})
        flop = sum(n for op, n in counts.items() if str(op).replace(".", "::") in MATMUL_OPS)  # aten.mm -> aten::mm
    matmul = matmul_time([(e.key, e.self_cpu_time_total / 1e6) for e in events], flop)
    rows = sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[:top]
    return {
        "iteration_s": timer.iteration_s[warmup],
        "step_s": timer.step_s[warmup],
        "user_s": timer.user_s[warmup],
        "sys_s": timer.sys_s[warmup],
        "minor_faults": timer.minor_faults[warmup],
        # below 1: the process waited for a CPU (a shared machine); the profiler's times are wall-clock times
        "cpu_over_wall": (timer.user_s[warmup] + timer.sys_s[warmup]) / timer.iteration_s[warmup],
        "warmup_s": [round(v, 4) for v in timer.iteration_s[:warmup]],
        "profiled_self_cpu_s": total_self / 1e6,
        **matmul,
        "threads": torch.get_num_threads(),
        "peak_rss_gib": peak_rss_gib(),
        "top_ops": [
            {"op": e.key, "calls": e.count, "self_cpu_s": e.self_cpu_time_total / 1e6,
             "self_share": e.self_cpu_time_total / max(total_self, 1), "cpu_total_s": e.cpu_time_total / 1e6}
            for e in rows
        ],
    }


MATMUL_OPS = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")


def matmul_time(events: list[tuple[str, float]], flop: int) -> dict[str, float]:
    """Of the profiled operators (name, self CPU seconds): the seconds in matrix products (the MLP's layers, forward
    and backward), with their `flop` the GFLOP and GFLOP/s (0 when not counted: no warm-up), and the seconds in
    everything else."""
    seconds = sum(s for name, s in events if name in MATMUL_OPS)
    return {"matmul_s": seconds, "matmul_gflop": flop / 1e9,
            "matmul_gflop_per_s": flop / 1e9 / seconds if seconds and flop else 0.0,
            "other_ops_s": sum(s for name, s in events if name not in MATMUL_OPS)}


def profile_table(result: dict) -> str:
    """The top operators of `profile_training` as a markdown table."""
    lines = ["| op | calls | self CPU s | share of self CPU | CPU total s (incl. children) |", "|---|---|---|---|---|"]
    for row in result["top_ops"]:
        lines.append(f"| `{row['op']}` | {row['calls']} | {row['self_cpu_s']:.3f} | {100 * row['self_share']:.1f}% "
                     f"| {row['cpu_total_s']:.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args, overrides, cli = training_args(sys.argv[1:] if argv is None else argv, __doc__,
                                         {"top": (25, "operators to list")},
                                         prog="python -m benchmarks.speed.profile_step")
    with stdout_to_stderr():
        result = profile_training(cli.model, cli.datamodule, args.warmup, args.precision, args.top, args.accelerator)
    record = {**record_header("profile", args, overrides), "warmup": args.warmup, **result}
    print(f"iteration {record['iteration_s']:.2f} s wall: user {record['user_s']:.2f} s, "
          f"system {record['sys_s']:.2f} s, {record['minor_faults']} minor page faults, {record['threads']} threads, "
          f"peak RSS {record['peak_rss_gib']:.2f} GiB")
    print(f"matrix products (aten::mm/addmm/bmm) {record['matmul_s']:.2f} s at {record['matmul_gflop_per_s']:.0f} "
          f"GFLOP/s ({record['matmul_gflop']:.0f} GFLOP), all other operators {record['other_ops_s']:.2f} s (self CPU "
          f"time)\n")
    print(profile_table(record))
    emit(record)
    return record


if __name__ == "__main__":
    main()
