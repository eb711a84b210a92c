"""tools/install_torch.sh (`make setup`'s torch): which build each machine gets, with a fake `nvidia-smi` on PATH, a
fake torch package in front of the real one, and pip's configuration from the environment only. Its --dry-run
prints the one pip command it would run; the decisions are the script's real code."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO

SCRIPT = REPO / "tools" / "install_torch.sh"
CPU_INDEX = "https://download.pytorch.org/whl/cpu"


@pytest.fixture
def machine(tmp_path):
    """run(gpu=..., torch=..., pip_sources=..., **env): the script's (first line, pip command) on a fake machine.
    gpu: True (nvidia-smi lists an H200), False (nvidia-smi there but failing: no driver), None (no nvidia-smi);
    torch: None (not importable) or (version, cuda version or None); pip_sources: PIP_* variables, no config files."""

    def run(gpu=None, torch=None, pip_sources=None, **env):
        bin_dir, fake = tmp_path / "bin", tmp_path / "site"
        bin_dir.mkdir(exist_ok=True)
        (fake / "torch").mkdir(parents=True, exist_ok=True)
        smi = bin_dir / "nvidia-smi"
        smi.unlink(missing_ok=True)
        if gpu is not None:
            smi.write_text("#!/bin/sh\necho 'GPU 0: NVIDIA H200 (UUID: GPU-0)'\n" if gpu else
                           "#!/bin/sh\necho 'NVIDIA-SMI has failed because it could not communicate with the "
                           "NVIDIA driver.'\nexit 9\n")
            smi.chmod(0o755)
        (fake / "torch" / "__init__.py").write_text(
            "raise ImportError('not installed')\n" if torch is None else
            f"import types\n__version__ = {torch[0]!r}\nversion = types.SimpleNamespace(cuda={torch[1]!r})\n")
        # PATH: the fake nvidia-smi and the basic tools only (no real nvidia-smi); pip reads no config file
        base = {k: v for k, v in os.environ.items() if not k.startswith("PIP_") and k != "TORCH_BUILD"}
        env = {**base, "PATH": f"{bin_dir}:/usr/bin:/bin", "PYTHONPATH": str(fake), "PIP_CONFIG_FILE": os.devnull,
               **(pip_sources or {}), **env}
        proc = subprocess.run(["bash", str(SCRIPT), "--dry-run", sys.executable], capture_output=True, text=True,
                              env=env, timeout=120)
        assert proc.returncode == 0, proc.stderr
        lines = proc.stdout.splitlines()
        commands = [x for x in lines if x.startswith(sys.executable)]
        assert commands in ([], lines[-1:])  # at most one command, the last line
        return lines[0], commands[0] if commands else None

    return run


def test_a_cpu_machine_gets_the_cpu_build(machine):
    for gpu in (None, False):  # no nvidia-smi, or one that finds no driver
        line, command = machine(gpu=gpu)
        assert line == f"install_torch: torch==2.13.0, the CPU build from {CPU_INDEX} (no NVIDIA GPU)"
        assert command == f"{sys.executable} -m pip install torch==2.13.0 --index-url {CPU_INDEX}"


def test_a_gpu_machine_gets_the_pinned_cuda_build(machine):
    line, command = machine(gpu=True)
    assert line == "install_torch: torch==2.13.0 from pip's sources, the CUDA build (nvidia-smi lists 1 GPU(s))"
    assert command == f"{sys.executable} -m pip install torch==2.13.0"


def test_an_installed_torch_that_satisfies_pyproject_is_kept(machine):
    requirement = re.search(r'"torch\s*([^";]*)"', (REPO / "pyproject.toml").read_text()).group(1)
    for torch, build in [(("2.9.1+cu128", "12.8"), "CUDA 12.8"), (("2.13.0+cpu", None), "CPU")]:
        for gpu in (True, None):
            line, command = machine(gpu=gpu, torch=torch)
            assert line == (f"install_torch: keeping the installed torch {torch[0]} ({build} build; pyproject.toml "
                            f"requires torch{requirement})")
            assert command is None
    # one older than pyproject's requirement is replaced
    line, command = machine(gpu=True, torch=("2.1.0+cu121", "12.1"))
    assert line == ("install_torch: replacing torch 2.1.0+cu121 (CUDA 12.1 build; pyproject.toml requires "
                    f"torch{requirement})")
    assert command == f"{sys.executable} -m pip install torch==2.13.0"


def test_a_configured_local_index_is_not_overridden(machine):
    """Where pip already has sources of its own (a mirror, a wheel folder), a command-line --index-url would replace
    them: the plain pin, from those; TORCH_BUILD=cpu still takes the CPU index, TORCH_BUILD=cuda the plain pin."""
    for sources in ({"PIP_FIND_LINKS": "/opt/wheels"}, {"PIP_INDEX_URL": "https://mirror.example/simple"},
                    {"PIP_EXTRA_INDEX_URL": "file:///opt/pypi/simple"}):
        line, command = machine(pip_sources=sources)
        assert line.startswith("install_torch: torch==2.13.0 from pip's configured sources (no NVIDIA GPU; pip "
                               f"config: :env:.{next(iter(sources))[4:].lower().replace('_', '-')}=")
        assert command == f"{sys.executable} -m pip install torch==2.13.0"
    line, command = machine(pip_sources={"PIP_FIND_LINKS": "/opt/wheels"}, TORCH_BUILD="cpu")
    assert line == f"install_torch: torch==2.13.0, the CPU build from {CPU_INDEX} (TORCH_BUILD=cpu)"
    assert command.endswith(f"--index-url {CPU_INDEX}")
    line, command = machine(gpu=None, TORCH_BUILD="cuda", TORCH_PIN="2.12.1")
    assert line == "install_torch: torch==2.12.1 from pip's sources, the CUDA build (TORCH_BUILD=cuda)"
    assert command == f"{sys.executable} -m pip install torch==2.12.1"


def test_bad_input_exits_2(tmp_path):
    proc = subprocess.run(["bash", str(SCRIPT), "--force"], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr == \
        "install_torch: unknown option --force (expected --dry-run and a Python)\n"
    proc = subprocess.run(["bash", str(SCRIPT), "--dry-run", sys.executable], capture_output=True, text=True,
                          env={**os.environ, "TORCH_BUILD": "rocm"})
    assert proc.returncode == 2 and proc.stderr == \
        "install_torch: TORCH_BUILD=rocm: expected cpu or cuda (or unset: decided by the machine)\n"
