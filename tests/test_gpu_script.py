"""benchmarks/speed/gpu.sh without a GPU: its dry run (every command, its time limit, nothing written), the one line it
stops with when there is no CUDA device, the fit's overrides through the real CLI, and its figures
(benchmarks/speed/gpu_report.py) from the JSON lines its steps leave."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys

import pytest
import torch

from benchmarks.speed import gpu_report
from tests.conftest import REPO

SCRIPT = REPO / "benchmarks" / "speed" / "gpu.sh"
STEPS = ["sfm", "benchmark_fp32", "benchmark_tf32", "benchmark_bf16", "release_equivalence", "fit", "test"]


def gpu_sh(*args: str, **env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("RELEASE_SRC", "SCENE", "OUT", "FIT_STEPS", "BUDGET")}
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=120,
                          env={**base, "PYTHON": sys.executable, **env})


def dry_run_commands(stdout: str) -> dict[str, tuple[int, list[str]]]:
    """`[name, at most N s] command...` lines -> name: (N, the command's words)."""
    commands = {}
    for line in stdout.splitlines():
        if line.startswith("["):
            head, command = line[1:].split("] ", 1)
            name, limit = head.split(", at most ")
            commands[name] = (int(limit.removesuffix(" s")), shlex.split(command))
    return commands


def test_dry_run_prints_every_step_and_writes_nothing(tmp_path):
    release = tmp_path / "SimpleNeRF" / "src"
    release.mkdir(parents=True)
    (release / "Trainer01.py").write_text("")
    out = tmp_path / "out"
    proc = gpu_sh("--dry-run", str(out), RELEASE_SRC=str(release), SIMPLENERF_SHARED=str(tmp_path / "shared"))
    assert proc.returncode == 0, proc.stderr
    commands = dry_run_commands(proc.stdout)
    assert list(commands) == STEPS
    assert sum(limit for limit, _ in commands.values()) <= 570  # under 10 minutes with the GPU query and summary
    assert not out.exists()
    fern = ["--data.init_args.scene_dir", str(tmp_path / "shared/data/nerf_llff_data/fern"),
            "--data.init_args.n_views", "2", "--data.init_args.factor", "4"]
    for name, precision in [("fp32", ["--precision", "32-true"]), ("tf32", ["--precision", "32-true", "--tf32"]),
                            ("bf16", ["--precision", "bf16-mixed"])]:
        words = commands[f"benchmark_{name}"][1]
        assert words[:5] == [sys.executable, "-m", "simplenerf", "benchmark", "--config"]
        assert words[5] == "configs/llff.yaml" and words[-7:] == ["--", *fern]
        assert words[-7 - len(precision):-7] == precision
    equivalence = commands["release_equivalence"][1]
    assert equivalence[1:3] == ["-m", "benchmarks.equivalence.check"]
    assert equivalence[equivalence.index("--device") + 1] == "cuda"
    assert equivalence[equivalence.index("--release-src") + 1] == str(release)
    assert equivalence[equivalence.index("--json") + 1] == str(out / "logs/release_equivalence.json")
    fit = commands["fit"][1]
    assert fit[fit.index("--trainer.max_steps") + 1] == "500" and fit[fit.index("--trainer.precision") + 1] == \
        "bf16-mixed" and fit[fit.index("--trainer.default_root_dir") + 1] == str(out / "fit")
    assert commands["test"][1][1:] == ["-m", "simplenerf", "test", "--config", str(out / "fit/config.yaml"),
                                      "--ckpt_path", "last"]

    # no release: its step is named as skipped, the others unchanged; a default output folder under runs/gpu/
    proc = gpu_sh("--dry-run", RELEASE_SRC=str(tmp_path / "none"), FIT_STEPS="40")
    assert proc.returncode == 0, proc.stderr
    assert f"# release_equivalence: skipped (recorded as such): no release at RELEASE_SRC={tmp_path / 'none'}" \
        in proc.stdout.splitlines()
    commands = dry_run_commands(proc.stdout)
    assert list(commands) == [s for s in STEPS if s != "release_equivalence"]
    fit = commands["fit"][1]
    assert fit[fit.index("--trainer.max_steps") + 1] == "40" and fit[fit.index("--trainer.val_check_interval") + 1] \
        == "20" and fit[fit.index("--trainer.default_root_dir") + 1].startswith("runs/gpu/20")


def test_usage_errors_exit_2():
    proc = gpu_sh("--fast")
    assert proc.returncode == 2 and proc.stderr == \
        "gpu.sh: unknown option --fast (expected --dry-run, --help or an output folder)\n"
    proc = gpu_sh("--dry-run", "a", "b")
    assert proc.returncode == 2 and proc.stderr == "gpu.sh: one output folder expected, got a and b\n"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device: gpu.sh would run for real")
def test_without_cuda_it_stops_with_one_line(tmp_path):
    out = tmp_path / "out"
    proc = gpu_sh(str(out))
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr == (f"gpu.sh: no CUDA device (torch.cuda.is_available() is not True for {sys.executable}): "
                           "nothing run\n")
    assert not out.exists()


def test_the_fits_overrides_are_the_clis(tmp_path):
    """The fit's command, as the dry run prints it, through the real CLI (--print_config): the overrides it says."""
    proc = gpu_sh("--dry-run", str(tmp_path / "out"), FIT_STEPS="500")
    fit = dry_run_commands(proc.stdout)["fit"][1]
    printed = subprocess.run([*fit, "--print_config"], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert printed.returncode == 0, printed.stderr
    import yaml

    config = yaml.safe_load(printed.stdout)
    trainer = config["trainer"]
    assert (trainer["max_steps"], trainer["precision"], trainer["val_check_interval"]) == (500, "bf16-mixed", 250)
    assert trainer["default_root_dir"] == str(tmp_path / "out" / "fit")
    schedules = [c["init_args"]["schedules"] for c in trainer["callbacks"] if c["class_path"].endswith("Schedule")]
    assert schedules == [{name: [[0, 0.0], [10, 0.1]] for name in ("points", "views", "cfc")}]
    assert config["checkpoint"]["every_n_train_steps"] == 500
    assert config["data"]["init_args"]["rays_per_batch"] == 2048  # the paper's step, unchanged


def test_without_wandb_the_fit_runs_with_no_logger(tmp_path):
    """A Python that cannot import wandb (a GPU machine given only the wheels it needs): the fit gets
    `--trainer.logger false`, said on stdout, and the CLI takes it."""
    blocker = tmp_path / "blocker"
    blocker.mkdir()
    (blocker / "wandb.py").write_text('raise ImportError("no wandb on this machine")\n')
    proc = gpu_sh("--dry-run", str(tmp_path / "out"), PYTHONPATH=str(blocker))
    assert proc.returncode == 0, proc.stderr
    assert f"# fit: {sys.executable} cannot import wandb: the fit runs with --trainer.logger false (no W&B run)" \
        in proc.stdout.splitlines()
    fit = dry_run_commands(proc.stdout)["fit"][1]
    assert fit[-2:] == ["--trainer.logger", "false"]
    printed = subprocess.run([*fit, "--print_config"], capture_output=True, text=True, cwd=REPO, timeout=300,
                             env={**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{blocker}"})
    assert printed.returncode == 0, printed.stderr
    import yaml

    assert yaml.safe_load(printed.stdout)["trainer"]["logger"] is False
    # with wandb importable: W&B, as configured
    fit = dry_run_commands(gpu_sh("--dry-run", str(tmp_path / "out")).stdout)["fit"][1]
    assert "--trainer.logger" not in fit


def test_report_records_each_step_and_summarises(tmp_path):
    out = tmp_path / "gpu"
    machine = tmp_path / "machine.json"
    machine.write_text(json.dumps({"gpu": "NVIDIA H200", "memory_gib": 139.8, "sms": 132, "driver": "570.1",
                                   "torch": "2.13.0", "cuda": "12.8", "commit": "abc1234",
                                   "date": "2027-01-02 10:00 UTC"}) + "\n")
    equivalence = tmp_path / "equivalence.json"
    equivalence.write_text(json.dumps({"check": "release_equivalence", "device": "cuda:0", "device_name":
                                       "cuda:0 (NVIDIA H200)", "rows": 400, "passed_rows": 399,
                                       "failed": ["step fern 2v float32 cuda:0 losses: L_cfc"]}) + "\n")
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({"scene": "fern", "frames": 3, "psnr": 17.123, "ssim": 0.51234, "lpips": 0.4321,
                                   "depth_mae": 0.2345, "depth_srocc": 0.6, "masked_psnr": 18.0}))
    checkpoint = tmp_path / "last.ckpt"
    torch.save({"global_step": 500, "state_dict": {}}, checkpoint)
    assert gpu_report.main(["record", str(out), "machine", "0", "0", "--from-json", str(machine)]) == 0
    assert gpu_report.main(["record", str(out), "release_equivalence", "1", "95.6", "--from-json",
                            str(equivalence)]) == 0
    assert gpu_report.main(["record", str(out), "fit", "124", "150", "--checkpoint", str(checkpoint)]) == 0
    assert gpu_report.main(["record", str(out), "test", "0", "40.2", "--test-summary", str(summary)]) == 0
    assert gpu_report.main(["record", str(out), "sfm", "1", "3", "--from-json", str(tmp_path / "absent.log")]) == 0
    assert gpu_report.main(["record", str(out), "late", "skipped", "0", "--note", "no time left"]) == 0
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert [(x["step"], x["status"]) for x in lines] == [("machine", 0), ("release_equivalence", 1), ("fit", 124),
                                                         ("test", 0), ("sfm", 1), ("late", "skipped")]
    assert lines[2]["global_step"] == 500 and lines[4]["measured"] is None
    assert lines[3]["test"] == {"frames": 3, "psnr": 17.123, "ssim": 0.51234, "lpips": 0.4321, "depth_mae": 0.2345,
                                "depth_srocc": 0.6}
    assert gpu_report.main(["summary", str(out)]) == 0
    assert (out / "summary.md").read_text() == """\
GPU: NVIDIA H200, 140 GiB; driver 570.1; torch 2.13.0, CUDA 12.8; commit abc1234; 2027-01-02 10:00 UTC

| step | status | wall s | s/it median (min-max) | peak GPU GiB (reserved) | result |
|---|---|---:|---|---|---|
| release_equivalence | 1 | 96 |  |  | 399 of 400 rows pass on cuda:0 (NVIDIA H200); FAIL: step fern 2v float32 cuda:0 \
losses: L_cfc |
| fit | time limit | 150 |  |  | reached step 500 |
| test | done | 40 |  |  | 3 frames: PSNR 17.12, SSIM 0.512, LPIPS 0.432, depth MAE 0.234 |
| sfm | 1 | 3 |  |  |  |
| late | skipped | 0 |  |  | no time left |
"""
    assert gpu_report.main(["summary", str(tmp_path / "empty")]) == 2
