"""The machine a run computes on (simplenerf.run.hardware): the CPU's capability from torch and /proc/cpuinfo's flags,
and the one-line warning when a precision has no fast kernels there, faked both ways; then through a real `fit`,
where the warning comes before the first step."""

from __future__ import annotations

import io
import sys

import pytest
import torch

from simplenerf.method.module import SimpleNeRF
from simplenerf.run import hardware
from simplenerf.run.cli import make_cli
from simplenerf.run.hardware import CPU, GPU, slow_precision
from tests.run.test_cli import run_args

XEON = {"fpu", "avx", "avx2", "avx512f", "avx512bw", "avx512vl", "avx512_vnni"}  # this project's Xeon: no bf16, no AMX


def fake_cpu(monkeypatch, torch_capability: str, flags: set[str] | None, machine: str = "x86_64") -> CPU:
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: torch_capability)
    monkeypatch.setattr(hardware, "cpu_flags", lambda: flags)
    monkeypatch.setattr(hardware.platform, "machine", lambda: machine)
    return hardware.cpu()


@pytest.mark.parametrize(
    ("torch_capability", "flags", "name", "bf16", "fp16"),
    [
        ("AVX2", {"avx", "avx2", "fma"}, "AVX2", False, False),  # the AMD EPYC
        ("AVX512", XEON, "AVX-512", False, False),
        ("AVX512", XEON | {"avx512_bf16"}, "AVX-512 BF16", True, False),  # e.g. Cooper Lake, Zen 4
        ("AVX512", XEON | {"avx512_bf16", "avx512_fp16", "amx_tile", "amx_bf16"}, "AMX", True, True),  # Sapphire R.
        ("AVX2", None, "AVX2", False, False),  # no /proc/cpuinfo: an AVX2 CPU has no bf16 extension
        ("AVX512", None, "AVX-512", None, None),  # no /proc/cpuinfo: unknown, nothing claimed
    ],
)
def test_the_cpu_capability_comes_from_torch_and_the_flags(monkeypatch, torch_capability, flags, name, bf16, fp16):
    cpu = fake_cpu(monkeypatch, torch_capability, flags)
    assert (cpu.capability, cpu.torch_capability, cpu.bf16, cpu.fp16) == (name, torch_capability, bf16, fp16)
    assert cpu.line().endswith(f"logical CPUs): {name}")


def test_another_architecture_names_torch_capability_and_claims_nothing(monkeypatch):
    cpu = fake_cpu(monkeypatch, "SVE256", {"fp", "asimd", "sve"}, machine="aarch64")
    assert (cpu.capability, cpu.bf16, cpu.fp16) == ("SVE256", None, None)
    assert slow_precision("bf16-mixed", torch.device("cpu"), cpu) is None


def test_reduced_precisions_warn_only_without_fast_kernels(monkeypatch):
    cpu_device = torch.device("cpu")
    avx2 = fake_cpu(monkeypatch, "AVX2", {"avx2"})
    for precision in ("bf16-mixed", "bf16-true"):
        line = slow_precision(precision, cpu_device, avx2)
        assert line.startswith(f"precision {precision} has no fast kernels on this CPU (AVX2, without AVX-512 BF16 or "
                               "AMX): PyTorch's reference bf16 matrix products run instead; measured: a step 2x (the "
                               "grid demo) to over 15x (the paper's config) slower than in 32-true on an AVX2 CPU")
        assert line.endswith("32-true is the fast precision here (--trainer.precision 32-true)")
    assert "without AVX-512 FP16 or AMX-FP16" in slow_precision("16-mixed", cpu_device, avx2)
    assert slow_precision("32-true", cpu_device, avx2) is None and slow_precision("64-true", cpu_device, avx2) is None
    xeon = fake_cpu(monkeypatch, "AVX512", XEON)
    assert "matrix products 3-4x and the grid demo's step 1.4x slower" in slow_precision("bf16-mixed", cpu_device, xeon)
    assert "matrix products 10x to 90x slower" in slow_precision("16-mixed", cpu_device, xeon)
    assert "not measured" in slow_precision("16-mixed", cpu_device, avx2)
    amx = fake_cpu(monkeypatch, "AVX512", XEON | {"avx512_bf16", "amx_tile", "amx_bf16"})
    assert slow_precision("bf16-mixed", cpu_device, amx) is None
    assert slow_precision("16-mixed", cpu_device, amx) is not None  # AMX-BF16 alone has no fp16
    unknown = fake_cpu(monkeypatch, "AVX512", None)
    assert slow_precision("bf16-mixed", cpu_device, unknown) is None


def test_a_gpu_without_bf16_is_named_and_warned_about(monkeypatch):
    avx2 = fake_cpu(monkeypatch, "AVX2", {"avx2"})
    cuda = torch.device("cuda", 0)
    turing, ampere = GPU("Tesla T4", (7, 5)), GPU("NVIDIA A100-SXM4-40GB", (8, 0))
    line = slow_precision("bf16-mixed", cuda, avx2, turing)
    assert line.startswith("precision bf16-mixed has no native bf16 on GPU Tesla T4 (compute capability 7.5): bf16 "
                           "needs compute capability 8.0 (Ampere) or newer")
    assert slow_precision("bf16-mixed", cuda, avx2, ampere) is None
    assert slow_precision("16-mixed", cuda, avx2, turing) is None  # fp16 kernels on every CUDA GPU
    monkeypatch.setattr(hardware, "gpu", lambda device: turing)
    out = io.StringIO()
    assert hardware.announce("bf16-mixed", cuda, out) == line
    first, second = out.getvalue().splitlines()
    assert first == f"simplenerf: {avx2.line()}; GPU Tesla T4 (compute capability 7.5); precision bf16-mixed"
    assert second == f"simplenerf: warning: {line}"


def test_fit_warns_before_the_first_step_on_a_cpu_without_bf16(tmp_path, monkeypatch, capsys):
    cpu = fake_cpu(monkeypatch, "AVX2", {"avx", "avx2"})
    original = SimpleNeRF.training_step

    def training_step(self, *args, **kwargs):
        print("FIRST STEP", file=sys.stderr, flush=True)
        monkeypatch.setattr(SimpleNeRF, "training_step", original)  # mark the first step only
        return original(self, *args, **kwargs)

    monkeypatch.setattr(SimpleNeRF, "training_step", training_step)
    make_cli(["fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--trainer.logger", "false",
              "--trainer.precision", "bf16-mixed"])
    lines = capsys.readouterr().err.splitlines()
    warning = f"simplenerf: warning: {slow_precision('bf16-mixed', torch.device('cpu'), cpu)}"
    assert lines.count(warning) == 1  # said once
    assert lines.index(f"simplenerf: {cpu.line()}; precision bf16-mixed") < lines.index(warning)
    assert lines.index(warning) < lines.index("FIRST STEP")


def test_fit_in_fp32_names_the_cpu_without_a_warning(tmp_path, monkeypatch, capsys):
    cpu = fake_cpu(monkeypatch, "AVX2", {"avx", "avx2"})
    make_cli(["fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--trainer.logger", "false"])
    err = capsys.readouterr().err
    assert f"simplenerf: {cpu.line()}; precision 32-true\n" in err
    assert "simplenerf: warning: precision" not in err
    assert "a GPU's budget" not in err  # one step of the demo's MLP


def test_a_cpu_fit_of_mlp_fields_past_the_budget_names_the_grid_config_before_the_first_step(
        tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(hardware, "GPU_BUDGET_STEPS", 0)  # the demo's MLP fields, one step past a budget of 0
    make_cli(["fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--trainer.logger", "false"])
    hint = hardware.cpu_budget_hint(torch.device("cpu"), True, 1)
    assert capsys.readouterr().err.splitlines().count(f"simplenerf: {hint}") == 1


def test_a_cpu_fit_of_the_papers_mlp_at_a_gpus_budget_points_to_the_grid():
    cpu, cuda = torch.device("cpu"), torch.device("cuda", 0)
    hint = hardware.cpu_budget_hint(cpu, True, 100000)
    assert hint is not None and "100000 steps" in hint and "configs/grid/simplerf_images4.yaml" in hint
    assert hardware.cpu_budget_hint(cuda, True, 100000) is None  # a GPU's budget on a GPU
    assert hardware.cpu_budget_hint(cpu, False, 100000) is None  # the grid on a CPU
    assert hardware.cpu_budget_hint(cpu, True, hardware.GPU_BUDGET_STEPS) is None  # a short MLP fit
    assert hardware.cpu_budget_hint(cpu, True, None) is None  # no step budget (max_epochs)


def test_subnormal_floats_are_flushed_unless_kept(monkeypatch):
    # 2**-126 / 2**9, below fp32's smallest normal, made from its bits (a conversion might already be flushed)
    subnormal = torch.tensor([1 << 14], dtype=torch.int32).view(torch.float32)
    try:
        monkeypatch.setenv("SIMPLENERF_DENORMALS", "keep")
        torch.set_flush_denormal(False)
        assert hardware.flush_denormals() is False
        assert (subnormal * 1.0).item() > 0  # kept: the CPU's default
        monkeypatch.delenv("SIMPLENERF_DENORMALS")
        assert hardware.flush_denormals() is True  # x86 with SSE3 and ARM: every machine this project runs on
        assert (subnormal * 1.0).item() == 0.0
        assert (torch.tensor([1e-37]) * 1.0).item() > 0  # a normal float stays
    finally:
        torch.set_flush_denormal(False)


def test_every_entry_point_flushes_subnormal_floats(monkeypatch, tmp_path):
    called = []
    monkeypatch.setattr(hardware, "flush_denormals", lambda: called.append(True) or True)
    make_cli([*run_args(tmp_path), "--trainer.logger", "false"], run=False)
    assert called == [True]
