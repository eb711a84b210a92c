"""Seconds per training step and peak memory of a configured model on this machine (`simplenerf benchmark`; the
scripts in benchmarks/ build on it).

Everything starts from the public CLI (`simplenerf.run.cli.make_cli(args, run=False)`): the model and data module are
the ones `simplenerf fit` would build, batches come from the data module, and Lightning runs the step (precision,
accelerator). The config's own trainer callbacks are NOT used, the warm-up `LossWeightSchedule` among them: every
loss is computed at its configured weight, i.e. the cost of a step after the paper's 10k-step warm-up (the release
computes its masked losses at weight 0 too, so this is also what the release pays from step 0).

Counting. A field evaluation is one query of one field (MLP, grid, ...) at one sample point. Per ray of a training
step, with S_c = `model.nerf.num_coarse`, S_f = `model.nerf.num_fine`, A_c / A_f = the augmentations evaluated at
the coarse / fine samples (the paper's are all coarse):

    E_train = S_c * (1 + A_c) + (S_c + S_f) * (1 + A_f)      (paper config: 64 * 3 + 192 = 384)
    E_render = S_c + (S_c + S_f)                             (augmentations are not rendered: 256)

and per iteration E_train * (random rays + sparse-depth rays). The matrix-product estimate counts only `nn.Linear`
layers: 2 * in * out FLOP per layer and point forward, 3x that forward + backward.

Timing. An iteration is timed from the end of the previous one to its own end (batch fetch, forward, losses,
backward, optimiser and scheduler step), after `warmup` untimed iterations; on CUDA each end is synchronised.
Memory: peak RSS is the process's `ru_maxrss` (data included), peak CUDA is `torch.cuda.max_memory_allocated`.
"""

from __future__ import annotations

import os
import platform
import resource
import statistics
import sys
import time

import lightning as L
import torch
from torch import nn

from simplenerf.data.scene import SceneDataModule
from simplenerf.method.module import SimpleNeRF
from simplenerf.run.hardware import announce

GIB = 2**30


def peak_rss_gib() -> float:
    """Peak resident memory of this process so far (Linux reports ru_maxrss in KiB, macOS in bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / GIB if sys.platform == "darwin" else peak / 2**20


def current_rss_gib() -> float | None:
    """Resident memory now (Linux only; None elsewhere)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def set_tf32(enabled: bool) -> None:
    """TF32 tensor-core matrix products and convolutions for fp32 tensors on Ampere and newer GPUs (no-op on CPUs)."""
    torch.backends.cuda.matmul.allow_tf32 = enabled
    torch.backends.cudnn.allow_tf32 = enabled
    torch.set_float32_matmul_precision("high" if enabled else "highest")


def device_name(device: torch.device) -> str:
    """A readable name of the device a run used (GPU model, else the CPU's)."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return f"{line.split(':', 1)[1].strip()} ({os.cpu_count()} logical CPUs)"
    except OSError:
        pass
    return platform.processor() or "cpu"


def field_evaluations_per_ray(model: SimpleNeRF, training: bool = True) -> int:
    """E_train or E_render (module docstring) of a SimpleNeRF module (`model.nerf`, `model.augmentations`)."""
    coarse, fine = model.nerf.num_coarse, model.nerf.num_coarse + model.nerf.num_fine
    total = coarse + fine
    if training:
        for aug in model.augmentations:
            total += fine if aug.stage == "fine" else coarse
    return total


def linear_macs(module: nn.Module) -> int:
    """Multiply-accumulates of the `nn.Linear` layers of `module` for one input point."""
    return sum(m.in_features * m.out_features for m in module.modules() if isinstance(m, nn.Linear))


def matmul_flop_per_ray(model: SimpleNeRF, training: bool = True) -> float:
    """Approximate matrix-product FLOP per ray (Linear layers only; x3 for forward + backward when training)."""
    nerf = model.nerf
    coarse, fine = nerf.num_coarse, nerf.num_coarse + nerf.num_fine
    macs = coarse * linear_macs(nerf.coarse) + fine * linear_macs(nerf.fine)
    if training:
        for aug in model.augmentations:
            samples = fine if aug.stage == "fine" else coarse
            macs += samples * linear_macs(aug.field)
    return 2.0 * macs * (3 if training else 1)


def spread(values: list[float], prefix: str) -> dict[str, float | list[float] | None]:
    return {
        prefix: statistics.median(values) if values else None,
        f"{prefix}_min": min(values) if values else None,
        f"{prefix}_max": max(values) if values else None,
        f"{prefix}_all": [round(v, 4) for v in values],
    }


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def synchronize(module: L.LightningModule) -> None:
    if module.device.type == "cuda":
        torch.cuda.synchronize(module.device)


class StepTimer(L.Callback):
    """Per training iteration: wall time end to end (from the previous iteration's end, so the batch fetch is in),
    wall time of the step alone (forward, backward, optimiser), and the process's user/system CPU time and minor page
    faults over the iteration."""

    def __init__(self) -> None:
        self.iteration_s: list[float] = []
        self.step_s: list[float] = []
        self.user_s: list[float] = []
        self.sys_s: list[float] = []
        self.minor_faults: list[int] = []
        self.rss_at_start_gib: float | None = None
        self.peak_rss_at_start_gib = 0.0
        self._last_end = self._start = 0.0
        self._usage = resource.getrusage(resource.RUSAGE_SELF)

    def on_train_start(self, trainer, pl_module) -> None:
        synchronize(pl_module)
        self.rss_at_start_gib, self.peak_rss_at_start_gib = current_rss_gib(), peak_rss_gib()
        if pl_module.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(pl_module.device)
        self._usage = resource.getrusage(resource.RUSAGE_SELF)
        self._last_end = time.perf_counter()

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        synchronize(pl_module)
        self._start = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        synchronize(pl_module)
        now = time.perf_counter()
        usage = resource.getrusage(resource.RUSAGE_SELF)
        self.iteration_s.append(now - self._last_end)
        self.step_s.append(now - self._start)
        self.user_s.append(usage.ru_utime - self._usage.ru_utime)
        self.sys_s.append(usage.ru_stime - self._usage.ru_stime)
        self.minor_faults.append(usage.ru_minflt - self._usage.ru_minflt)
        self._last_end, self._usage = now, usage


def measuring_trainer(precision: str, accelerator: str, devices: int | str, **kwargs) -> L.Trainer:
    return L.Trainer(
        precision=precision,
        accelerator=accelerator,
        devices=devices,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        **kwargs,
    )


def cuda_peaks(device: torch.device) -> dict[str, float | None]:
    if device.type != "cuda":
        return {"peak_cuda_gib": None, "peak_cuda_reserved_gib": None}
    return {
        "peak_cuda_gib": torch.cuda.max_memory_allocated(device) / GIB,
        "peak_cuda_reserved_gib": torch.cuda.max_memory_reserved(device) / GIB,
    }


def rays_per_iteration(datamodule: SceneDataModule) -> tuple[int, int]:
    """(random rays, sparse-depth rays) a training batch of `datamodule` holds."""
    return int(datamodule.rays_per_batch), int(datamodule.sparse_rays_per_batch)


def time_training(
    model: SimpleNeRF,
    datamodule: SceneDataModule,
    steps: int,
    warmup: int,
    precision: str,
    accelerator: str = "auto",
    devices: int | str = 1,
) -> dict:
    """Trains warmup + steps iterations and reports the timed ones (see the module docstring for what is counted).

    Returns a flat dict: s_per_it (median; _min, _max, _all), step_s (the step alone, median), rays_per_s and
    field_evaluations_per_s (at the median), approximate matmul TFLOP/s, user/sys CPU seconds and minor page faults
    per iteration (medians), peak_rss_gib, rss_at_start_gib, peak_cuda_gib (None without CUDA), the loss weights and
    the last step's losses (which terms were computed).
    """
    if steps < 1 or warmup < 0:
        raise ValueError(f"need steps >= 1 and warmup >= 0, got {steps}, {warmup}")
    timer = StepTimer()
    trainer = measuring_trainer(precision, accelerator, devices, max_steps=warmup + steps, callbacks=[timer])
    announce(trainer.precision, trainer.strategy.root_device)  # the CPU; a warning when the precision is slow on it
    datamodule.setup("fit")
    model.set_train_views(datamodule.train_views)
    trainer.fit(model, datamodule)
    timed = timer.iteration_s[warmup:]
    if len(timed) < steps:
        raise RuntimeError(f"only {len(timer.iteration_s)} of {warmup + steps} iterations ran (epoch too short?)")
    rays, sparse = rays_per_iteration(datamodule)
    evaluations = field_evaluations_per_ray(model) * (rays + sparse)
    flop = matmul_flop_per_ray(model) * (rays + sparse)
    result = {
        "rays_random": rays,
        "rays_sparse": sparse,
        "rays_per_it": rays + sparse,
        "field_evaluations_per_ray": field_evaluations_per_ray(model),
        "field_evaluations_per_it": evaluations,
        "approx_matmul_tflop_per_it": flop / 1e12,
        **spread(timed, "s_per_it"),
        "step_s": statistics.median(timer.step_s[warmup:]),
        "user_s_per_it": statistics.median(timer.user_s[warmup:]),
        "sys_s_per_it": statistics.median(timer.sys_s[warmup:]),
        "minor_faults_per_it": statistics.median(timer.minor_faults[warmup:]),
        "cpu_s_all": [round(u + s, 4) for u, s in zip(timer.user_s[warmup:], timer.sys_s[warmup:], strict=True)],
        "warmup_s": [round(v, 4) for v in timer.iteration_s[:warmup]],
    }
    median = result["s_per_it"]
    result.update(
        rays_per_s=(rays + sparse) / median,
        field_evaluations_per_s=evaluations / median,
        approx_matmul_tflops=flop / median / 1e12,
        peak_rss_gib=peak_rss_gib(),
        peak_rss_at_train_start_gib=timer.peak_rss_at_start_gib,
        rss_at_start_gib=timer.rss_at_start_gib,
        **cuda_peaks(model.device),
        device=device_name(model.device),
        loss_weights={name: float(term.weight) for name, term in model.terms.items()},
        losses={k.removeprefix("train/loss_"): float(v) for k, v in trainer.callback_metrics.items()
                if k.startswith("train/loss_")},
    )
    return result
