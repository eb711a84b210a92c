"""The machine a run computes on, and whether its precision has fast kernels there.

A run (fit, validate, test, predict, `simplenerf benchmark`) names the CPU and what its vector units can do in one
line, and warns once, in one line, when the chosen precision has no fast matrix-product kernels on its device:

- CPU, bf16 (`bf16-mixed`, `bf16-true`): fast kernels (oneDNN) need AVX-512 BF16 or AMX; without them PyTorch falls
  back to its reference bf16 GEMM (`cpublas_gemm_impl`). Measured (docs/benchmarks.md): on a 2-core AMD EPYC with
  AVX2, the grid demo 2x slower than 32-true and the paper's config more than 15x slower (over 100 s against 7 s a
  step); on a 2-core Intel Xeon with AVX-512 and no AVX-512 BF16, the MLP's products alone 3-4x slower and the grid
  demo's step 1.4x (CPU time).
- CPU, fp16 (`16-mixed`, `16-true`): fast kernels need AVX-512 FP16 or AMX-FP16; without them the products alone were
  10x to 90x slower than fp32 on that Xeon.
- GPU, bf16: native from compute capability 8.0 (Ampere); older GPUs emulate it, with no speed-up over fp32.

What the CPU can do is read from `torch.backends.cpu.get_cpu_capability()` (the kernels torch dispatches to) and, for
the bf16/fp16 extensions torch does not report, the flags of /proc/cpuinfo (Linux, x86). Where the flags cannot be read
(no /proc/cpuinfo, another architecture), bf16/fp16 support is unknown and nothing is claimed. The configs keep the
release's fp32 (`32-true`, Lightning's default where a config does not set it): it is fast on every CPU, and a run's
numbers do not depend on the machine it was trained on.

Every entry point also flushes subnormal floats to zero on the CPU (`flush_denormals`): a grid fit's densities run
to exp(-90) and below in empty space, ~1% of the values its matrix products and grid-sample backward read are then
subnormal (below 1.2e-38 in fp32), and x86 CPUs take a microcode assist of 100+ cycles on each. Measured on fern at
images_4 (docs/benchmarks.md, "Subnormal floats"): a step of `simplerf_images4.yaml` from its step-1200 and
step-3200 checkpoints 1.41x and 1.28x as fast, from step 400 (before the densities get there) unchanged.
SIMPLENERF_DENORMALS=keep leaves the CPU's default.
"""

from __future__ import annotations

import os
import platform
import sys
from dataclasses import dataclass
from typing import TextIO

import torch
from lightning.pytorch.utilities import rank_zero_only


def flush_denormals() -> bool:
    """Subnormal floats read and written as zero on the CPU from now on, in this thread and the threads it starts
    (`torch.set_flush_denormal`: x86 DAZ and FTZ, which need SSE3; ARM's FZ). Values below 1.2e-38 in fp32 count for
    nothing in a loss or a gradient but cost a microcode assist each (see the module docstring). Not with
    SIMPLENERF_DENORMALS=keep (to measure the difference). Returns whether it applied."""
    if os.environ.get("SIMPLENERF_DENORMALS", "flush") == "keep":
        return False
    return torch.set_flush_denormal(True)


# x86 flags of /proc/cpuinfo (Linux's names) that give fast reduced-precision matrix products.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")
FP16_FLAGS = ("avx512_fp16", "amx_fp16")

# The expected cost of a precision without fast kernels, by the CPU's capability (measured: docs/benchmarks.md).
CPU_SLOWDOWN = {
    ("bf16", "AVX2"): "a step 2x (the grid demo) to over 15x (the paper's config) slower than in 32-true on an AVX2 "
                      "CPU",
    ("bf16", "AVX-512"): "the matrix products 3-4x and the grid demo's step 1.4x slower than in 32-true on an AVX-512 "
                         "CPU without AVX-512 BF16",
    ("fp16", "AVX-512"): "the matrix products 10x to 90x slower than in 32-true on an AVX-512 CPU without AVX-512 FP16",
}


@dataclass(frozen=True)
class CPU:
    """The CPU of this machine. `capability`: AVX2, AVX-512, AVX-512 BF16 or AMX (x86), else torch's own name (e.g.
    DEFAULT, SVE256); `torch_capability`: the kernels torch dispatches to; `bf16` / `fp16`: whether bf16 / fp16 matrix
    products have fast kernels (None: unknown, the flags could not be read)."""

    model: str
    logical_cpus: int
    capability: str
    torch_capability: str
    bf16: bool | None
    fp16: bool | None

    def line(self) -> str:
        return f"CPU {self.model} ({self.logical_cpus} logical CPUs): {self.capability}"


@dataclass(frozen=True)
class GPU:
    """A CUDA device: its model and compute capability; `bf16`: native bf16 (8.0, Ampere, and newer)."""

    model: str
    compute_capability: tuple[int, int]

    @property
    def bf16(self) -> bool:
        return self.compute_capability >= (8, 0)

    def line(self) -> str:
        major, minor = self.compute_capability
        return f"GPU {self.model} (compute capability {major}.{minor})"


def cpu_flags() -> set[str] | None:
    """The CPU's feature flags from /proc/cpuinfo (`flags` on x86, `Features` on ARM); None where it cannot be read."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in ("flags", "Features"):
                    return set(value.split())
    except OSError:
        pass
    return None


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def cpu() -> CPU:
    """This machine's CPU (`cpu_flags`, `cpu_model` and torch's capability)."""
    torch_capability = torch.backends.cpu.get_cpu_capability()
    flags = cpu_flags()
    if platform.machine().lower() not in ("x86_64", "amd64", "i386", "i686"):
        return CPU(cpu_model(), os.cpu_count() or 1, torch_capability, torch_capability, None, None)
    if flags is None:  # x86 without /proc/cpuinfo (macOS, Windows): only what torch says
        avx2_only = torch_capability in ("AVX2", "DEFAULT")  # the bf16/fp16 extensions all come with AVX-512
        name = {"AVX512": "AVX-512"}.get(torch_capability, torch_capability)
        known = False if avx2_only else None
        return CPU(cpu_model(), os.cpu_count() or 1, name, torch_capability, known, known)
    bf16 = any(f in flags for f in BF16_FLAGS)
    fp16 = any(f in flags for f in FP16_FLAGS)
    if "amx_bf16" in flags or "amx_tile" in flags:
        name = "AMX"
    elif "avx512_bf16" in flags:
        name = "AVX-512 BF16"
    elif torch_capability == "AVX512" or "avx512f" in flags:
        name = "AVX-512"
    elif torch_capability == "AVX2" or "avx2" in flags:
        name = "AVX2"
    else:
        name = torch_capability
    return CPU(cpu_model(), os.cpu_count() or 1, name, torch_capability, bf16, fp16)


def gpu(device: torch.device) -> GPU:
    return GPU(torch.cuda.get_device_name(device), tuple(torch.cuda.get_device_capability(device)))


def reduced_dtype(precision: str) -> str | None:
    """"bf16" or "fp16" for a Lightning precision that computes matrix products in it, else None (fp32, fp64)."""
    if precision.startswith("bf16"):
        return "bf16"
    if precision.startswith("16"):
        return "fp16"
    return None


def slow_precision(precision: str, device: torch.device, machine_cpu: CPU, machine_gpu: GPU | None = None
                   ) -> str | None:
    """The warning line (without the program's prefix) when `precision` has no fast kernels on `device`, else None."""
    dtype = reduced_dtype(str(precision))
    if dtype is None:
        return None
    if device.type == "cuda":
        if dtype == "bf16" and machine_gpu is not None and not machine_gpu.bf16:
            return (f"precision {precision} has no native bf16 on {machine_gpu.line()}: bf16 needs compute "
                    "capability 8.0 (Ampere) or newer, and is emulated here with no speed-up over 32-true; use "
                    "--trainer.precision 16-mixed or 32-true")
        return None
    if device.type != "cpu" or getattr(machine_cpu, dtype) is not False:
        return None
    needs = "AVX-512 BF16 or AMX" if dtype == "bf16" else "AVX-512 FP16 or AMX-FP16"
    base = "AVX2" if machine_cpu.capability == "AVX2" else "AVX-512"
    cost = CPU_SLOWDOWN.get((dtype, base), "not measured; expect the matrix products several times slower")
    return (f"precision {precision} has no fast kernels on this CPU ({machine_cpu.capability}, without {needs}): "
            f"PyTorch's reference {dtype} matrix products run instead; measured: {cost} (docs/benchmarks.md). "
            "32-true is the fast precision here (--trainer.precision 32-true)")


def announce(precision: str, device: torch.device, stream: TextIO | None = None, prog: str = "simplenerf"
             ) -> str | None:
    """Prints the machine line (`<prog>: CPU ...: AVX-512; [GPU ...;] precision P`) and, when `precision` is slow on
    `device`, the warning line, on `stream` (default stderr); under DDP only rank 0 prints. Returns the warning (None
    when there is none)."""
    stream = sys.stderr if stream is None else stream
    machine_cpu = cpu()
    machine_gpu = gpu(device) if device.type == "cuda" else None
    parts = [machine_cpu.line(), *([machine_gpu.line()] if machine_gpu else []), f"precision {precision}"]
    warning = slow_precision(precision, device, machine_cpu, machine_gpu)
    if getattr(rank_zero_only, "rank", 0) == 0:
        print(f"{prog}: {'; '.join(parts)}", file=stream, flush=True)
        if warning is not None:
            print(f"{prog}: warning: {warning}", file=stream, flush=True)
    return warning


# Above this many steps an MLP fit is a GPU's budget (the paper's configs: 100k steps, 2-8 s a step on this project's
# CPUs, docs/benchmarks.md): on a CPU, days.
GPU_BUDGET_STEPS = 20000


def cpu_budget_hint(device: torch.device, mlp_fields: bool, max_steps: int | None) -> str | None:
    """The line (without the program's prefix) that points a CPU fit of the paper's MLP at a GPU's budget to the
    grid configs, else None: `mlp_fields`, the main NeRF has an MLP field (`model.fields.RadianceField`)."""
    if device.type != "cpu" or not mlp_fields or max_steps is None or max_steps <= GPU_BUDGET_STEPS:
        return None
    return (f"this fit trains the paper's MLP fields for {max_steps} steps, a GPU's budget: on a CPU that takes days "
            "(the progress line's eta says how many). Without a GPU, train the grid instead: "
            "configs/grid/simplerf_images4.yaml, at the paper's resolution in 1-2 hours of one CPU thread "
            "(README, \"Your own photos\")")


def machine_record(device: torch.device | None = None) -> dict:
    """The machine as the fields of a benchmark's JSON: CPU model and capability, torch's dispatch, and the GPU model
    and compute capability (None without a GPU; `device`: the one measured, default CUDA's current one if any)."""
    machine_cpu = cpu()
    if device is None and torch.cuda.is_available():
        device = torch.device("cuda", torch.cuda.current_device())
    machine_gpu = gpu(device) if device is not None and device.type == "cuda" else None
    return {
        "cpu": machine_cpu.model,
        "cpu_capability": machine_cpu.capability,
        "torch_cpu_capability": machine_cpu.torch_capability,
        "logical_cpus": machine_cpu.logical_cpus,
        "gpu": machine_gpu.model if machine_gpu else None,
        "gpu_compute_capability": ".".join(map(str, machine_gpu.compute_capability)) if machine_gpu else None,
    }
