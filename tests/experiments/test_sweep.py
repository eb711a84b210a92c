"""`simplenerf sweep` end to end on generated synthetic scenes (48x64, exact depth, a few steps per fit): the debug
executor over 2 scenes x 2 view counts x 2 models with the table at the end, the local executor with 2 jobs at once and
a run killed mid-way then resumed, bad input stopping before anything runs, and the SLURM path (dry-run scripts,
submitit's own submission with a stand-in sbatch, Lightning's requeue under a faked SLURM environment)."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
from datetime import datetime
from pathlib import Path
from unittest import mock

import pytest
import torch
import yaml

from simplenerf.commands import main
from simplenerf.experiments.executors import submit_slurm, units_to_run
from simplenerf.experiments.jobs import run_unit
from simplenerf.experiments.plan import build_plan
from simplenerf.experiments.spec import SweepError, load_sweep
from simplenerf.experiments.state import read_state
from simplenerf.experiments.status import status_table
from tests.conftest import REPO
from tests.experiments.sweep_fixtures import (
    Preempted,
    callbacks_override,
    models,
    synthetic_scenes,
    tiny_configs,
    write_sweep,
)


def wandb_run_id(folder_name: str) -> str:
    """The run id in W&B's offline folder name `offline-run-<time>-<id>`; W&B appends `-1`, `-2`, ... when two runs
    start in the same second (a quick resume), so that suffix is not part of the id."""
    return re.sub(r"-\d+$", "", folder_name.removeprefix("offline-run-").split("-", 1)[1])


def sweep_cli(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true", "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "simplenerf", "sweep", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def debug_sweep(tmp_path_factory):
    """2 scenes (one scored against its exact depth, one against a tiny dense NeRF's) x 2 and 3 views x SimpleNeRF and
    DS-NeRF, debug executor, in this process."""
    tmp = tmp_path_factory.mktemp("debug_sweep")
    configs = tiny_configs(tmp / "configs")
    scenes = synthetic_scenes(tmp / "data")
    path = write_sweep(tmp / "sweep.yaml", [{"path": str(scenes[0]), "reference_depth": "scene"},
                                            {"path": str(scenes[1])}], [2, 3], models(configs), configs, tmp / "out")
    main(["sweep", "--config", str(path)])
    return tmp


def test_debug_sweep_runs_every_stage_and_writes_the_table(debug_sweep, capsys):
    out = debug_sweep / "out"
    runs = sorted(p.parent.parent for p in (out / "runs").glob("*/*/*/*/test/summary.json"))
    assert len(runs) == 8
    for run in runs:
        assert read_state(run, "fit")["status"] == "done" and read_state(run, "test")["status"] == "done"
        assert torch.load(run / "checkpoints" / "last.ckpt", weights_only=False)["global_step"] == 4
    # scene1 has no depth of its own in the sweep's eyes: a dense NeRF was trained and its depth exported.
    assert len(list((out / "dense" / "scene1" / "depth").glob("*.npy"))) == 20
    assert not (out / "dense" / "scene0").exists()
    assert {p.name for p in (out / "masks" / "scene1" / "2v").glob("*.png")} == {"000.png", "008.png", "016.png"}
    table = (out / "results.md").read_text()
    assert "| SimpleNeRF (paper) | 0.2688 | 0.6501 | 19.57 |" in table  # the published row beside the measured ones
    measured = [line for line in table.splitlines() if line.startswith(("| SimpleNeRF |", "| DS-NeRF |"))]
    assert len(measured) == 2 and all(line.count(" - ") <= 7 for line in measured)  # 2 and 3 views filled
    with open(out / "results.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["source"] == "measured"]
    assert {(r["model"], r["n_views"]) for r in rows} == {(m, n) for m in ("SimpleNeRF", "DS-NeRF") for n in "23"}
    assert all(r["scenes"] == "scene0;scene1" for r in rows)
    capsys.readouterr()
    main(["sweep", "status", str(out)])
    status = capsys.readouterr().out
    assert "| fit | scene1 | 3 | DS-NeRF | 0 | done | 4/4 |" in status and "23 jobs: 23 done" in status


def test_runs_share_a_wandb_group_and_fit_and_test_share_a_wandb_run(debug_sweep):
    run = debug_sweep / "out" / "runs" / "scene0" / "2v" / "DS-NeRF" / "seed0"
    logger = yaml.safe_load((run / "config.yaml").read_text())["trainer"]["logger"]["init_args"]
    assert logger["group"] == "tiny" and logger["tags"] == ["scene0", "2v", "DS-NeRF", "seed0"]
    started = sorted(p.name for p in (run / "wandb").glob("offline-run-*"))
    assert len(started) == 2 and len({wandb_run_id(name) for name in started}) == 1  # the same W&B run id


def test_rerun_skips_what_finished(debug_sweep):
    out = debug_sweep / "out"
    summary = out / "runs" / "scene1" / "2v" / "SimpleNeRF" / "seed0" / "test" / "summary.json"
    before = summary.stat().st_mtime_ns
    plan = build_plan(load_sweep(debug_sweep / "sweep.yaml"), debug_sweep / "sweep.yaml")
    assert [u.stage for u in units_to_run(plan)] == ["table"]
    main(["sweep", "--config", str(debug_sweep / "sweep.yaml")])
    assert summary.stat().st_mtime_ns == before
    assert read_state(summary.parent.parent, "fit")["attempts"] == 1


def test_a_run_folder_never_mixes_two_configs(debug_sweep, tmp_path):
    sweep = yaml.safe_load((debug_sweep / "sweep.yaml").read_text())
    sweep["budget"] = {"max_steps": 6}  # another config for the same run folders
    path = tmp_path / "longer.yaml"
    path.write_text(yaml.safe_dump(sweep))
    with pytest.raises(SweepError, match=r"fit scene0/2v/SimpleNeRF/seed0: .* holds a run of another config"):
        build_plan(load_sweep(path), path)


def test_bad_input_stops_before_anything_runs(tmp_path):
    configs = tiny_configs(tmp_path / "configs")
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    good = {"path": str(scene), "reference_depth": "scene"}
    broken = tmp_path / "configs" / "broken.yaml"
    broken.write_text("model:\n  no_such_option: 1\n")
    cases = {
        "missing scene": ([good, {"path": str(tmp_path / "nowhere")}], models(configs), {},
                          r"scenes\[1\]: scene folder .*nowhere does not exist"),
        "unknown key": ([good], models(configs), {"budget": {"max_step": 3}},
                        r"sweep\.yaml: .*budget.* does not accept option 'max_step'"),
        "unknown key in an entry": ([good], [{**models(configs)[0], "extra": 1}], {},
                                    r"sweep\.yaml: models: class_path simplenerf\.experiments\.spec\.ModelEntry: "
                                    r"Option 'extra' is not accepted$"),
        "model does not parse": ([good], [{"name": "Broken", "configs": [str(configs["simplenerf"]), str(broken)]}],
                                 {}, r"models\[0\] \(Broken\) on scenes\[0\] \(scene0\): .*no_such_option"),
    }
    for name, (scenes, model_list, more, message) in cases.items():
        out = tmp_path / name.replace(" ", "_")
        path = write_sweep(tmp_path / "sweep.yaml", scenes, [2], model_list, configs, out, **more)
        proc = sweep_cli("--config", str(path))
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1, (name, proc.stderr)
        assert lines[0].startswith("simplenerf: error: "), name
        assert re.search(message, lines[0]), (name, lines[0])
        assert not out.exists(), name  # nothing written, nothing submitted


def test_local_executor_two_at_once_and_a_killed_run_resumes(tmp_path):
    """Two fits at once in their own processes; SimpleNeRF's is killed (SIGKILL) at step 3 of 6, after its step-2
    checkpoint. The sweep ends failed with DS-NeRF tested; run again, it resumes SimpleNeRF from step 2 and leaves
    DS-NeRF's run untouched."""
    configs = tiny_configs(tmp_path / "configs", steps=6)
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    kill = callbacks_override(tmp_path / "configs", "kill", "KillOnceAt", step=3)
    model_list = models(configs)
    model_list[0]["configs"].append(str(kill))
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "scene"}], [2], model_list,
                       configs, tmp_path / "out", executor="local", resources={"concurrent_jobs": 2})
    with pytest.raises(SystemExit) as first:  # the sweep here, its jobs in processes of their own
        main(["sweep", "--config", str(path)])
    assert first.value.code == 1
    runs = tmp_path / "out" / "runs" / "scene0" / "2v"
    simple, ds = runs / "SimpleNeRF" / "seed0", runs / "DS-NeRF" / "seed0"
    assert (ds / "test" / "summary.json").is_file() and not (simple / "test").exists()
    killed, finished = read_state(simple, "fit"), read_state(ds, "fit")
    assert killed["status"] == "running" and finished["status"] == "done"  # SIGKILL left no time to record it
    # Jobs in their own processes, two at a time: the masks job and the two fits, some two of them overlapping.
    masks = read_state(tmp_path / "out" / "masks" / "scene0" / "2v", "masks")
    t = datetime.fromisoformat
    killed_at = (tmp_path / "configs" / "kill.marker").stat().st_mtime
    kill_time = datetime.fromtimestamp(killed_at, tz=t(killed["started"]).tzinfo)
    spans = [(t(masks["started"]), t(masks["ended"])), (t(finished["started"]), t(finished["ended"])),
             (t(killed["started"]), kill_time)]
    assert any(a[0] < b[1] and b[0] < a[1] for i, a in enumerate(spans) for b in spans[i + 1 :]), spans
    assert len({masks["pid"], finished["pid"], killed["pid"]}) == 3
    status = status_table(tmp_path / "out")
    assert "| fit | scene0 | 2 | SimpleNeRF | 0 | stopped | 2/6 |" in status
    assert "| test | scene0 | 2 | SimpleNeRF | 0 | pending |" in status
    step2 = simple / "checkpoints" / "step000002.ckpt"
    untouched = {p: p.stat().st_mtime_ns for p in [step2, *ds.rglob("*.ckpt"), ds / "test" / "summary.json"]}

    main(["sweep", "--config", str(path)])
    assert {p: p.stat().st_mtime_ns for p in untouched} == untouched  # not started over; the finished run untouched
    assert torch.load(simple / "checkpoints" / "last.ckpt", weights_only=False)["global_step"] == 6
    assert read_state(simple, "fit")["attempts"] == 2 and read_state(ds, "fit")["attempts"] == 1
    assert (simple / "test" / "summary.json").is_file()
    assert "| SimpleNeRF |" in (tmp_path / "out" / "results.md").read_text()


@pytest.fixture
def table1_sweep(tmp_path) -> Path:
    """configs/sweeps/llff_table1.yaml with its output in tmp_path (its scenes need not exist for a dry run)."""
    sweep = yaml.safe_load((REPO / "configs" / "sweeps" / "llff_table1.yaml").read_text())
    sweep["output"] = str(tmp_path / "out")
    path = tmp_path / "llff_table1.yaml"
    path.write_text(yaml.safe_dump(sweep, sort_keys=False))
    return path


def test_slurm_dry_run_writes_scripts_a_user_submits_as_they_are(table1_sweep, tmp_path):
    proc = sweep_cli("--config", str(table1_sweep), "--executor", "slurm", "--dry-run")
    assert proc.returncode == 0, proc.stderr
    folder = tmp_path / "out" / "slurm"
    fit = (folder / "fit.sbatch").read_text()
    n_fits = len(json.loads((folder / "fit.json").read_text()))
    assert n_fits == 8 * 3 * 2  # 8 scenes x 3 views x SimpleNeRF and DS-NeRF
    for line in (f"#SBATCH --array=0-{n_fits - 1}%", "#SBATCH --signal=USR1@90", "#SBATCH --gpus-per-node=1",
                 "#SBATCH --cpus-per-task=", "#SBATCH --time=", "#SBATCH --kill-on-invalid-dep=yes",
                 f"#SBATCH --chdir={REPO}", "-m simplenerf sweep job", "${SLURM_ARRAY_TASK_ID}", "srun "):
        assert line in fit, line
    submit = (folder / "submit.sh").read_text()
    test_line = f"test=$(sbatch --parsable --dependency=afterok:${{masks%%;*}}:${{fit%%;*}} {folder / 'test.sbatch'})"
    assert test_line in submit
    assert f"table=$(sbatch --parsable --dependency=afterany:${{test%%;*}} {folder / 'table.sbatch'})" in submit
    # submit.sh as it is, with a stand-in sbatch that records its arguments
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "sbatch").write_text('#!/bin/bash\necho "$@" >> "$(dirname "$0")/calls"\necho $((RANDOM + 1000))\n')
    (bin_dir / "sbatch").chmod(0o755)
    path = f"{bin_dir}:{os.environ['PATH']}"
    run = subprocess.run(["bash", str(folder / "submit.sh")], env={**os.environ, "PATH": path}, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr
    calls = (bin_dir / "calls").read_text().splitlines()
    stages = ("dense", "depth", "masks", "fit", "test", "table")
    assert [Path(c.split()[-1]).name for c in calls] == [f"{s}.sbatch" for s in stages]
    assert "--dependency=afterok:" in calls[4]


def test_slurm_submission_through_submitit(table1_sweep, tmp_path, monkeypatch):
    """The real path: submitit writes and submits one array per stage (here to a stand-in sbatch), dependencies and
    Lightning's requeue signal in the scripts; submitit's own preemption signal is not the one SLURM sends."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "sbatch").write_text('#!/bin/bash\nd=$(dirname "$0"); n=$(( $(cat "$d/n" 2>/dev/null || echo 1000) + 1'
                                    '))\necho $n > "$d/n"; cp "${@: -1}" "$d/$n.sh"; echo "Submitted batch job $n"\n')
    (bin_dir / "sbatch").chmod(0o755)
    (bin_dir / "srun").write_text("#!/bin/bash\n")  # submitit checks that it is on a SLURM machine
    (bin_dir / "srun").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}:{os.environ['PATH']}")
    sweep = yaml.safe_load(table1_sweep.read_text())
    for scene in sweep["scenes"]:  # the plan needs the scenes to exist for a real submission
        scene["path"] = str(tmp_path / "scenes" / Path(scene["path"]).name)
        Path(scene["path"]).mkdir(parents=True)
    table1_sweep.write_text(yaml.safe_dump(sweep))
    plan = build_plan(load_sweep(table1_sweep), table1_sweep)
    ids = submit_slurm(plan, units_to_run(plan), log=lambda *a: None)
    assert list(ids) == ["dense", "depth", "masks", "fit", "test", "table"]
    scripts = {p.name: p.read_text() for p in bin_dir.glob("*.sh")}
    test = scripts[f"{ids['test']}.sh"]
    assert f"#SBATCH --dependency=afterok:{ids['masks']}:{ids['fit']}" in test or \
        f"#SBATCH --dependency=afterok:{ids['fit']}:{ids['masks']}" in test
    assert "#SBATCH --signal=USR1@90" in test and "submitit.core._submit" in test
    from submitit.core.job_environment import JobEnvironment

    assert JobEnvironment.USR_SIG == "USR2"  # submitit's requeue signal; SLURM sends USR1, Lightning's
    assert not hasattr(run_unit, "checkpoint")  # and submitit would not checkpoint or requeue it anyway


def test_requeue_under_slurm_continues_in_the_same_folder_and_wandb_run(tmp_path, monkeypatch):
    """As Lightning's own tests: a faked SLURM environment, SIGUSR1 during fit -> Lightning saves hpc_ckpt_1.ckpt and
    calls `scontrol requeue <array>_<task>`; the requeued job (run_unit again) resumes in the same run folder, with the
    same W&B run id, and finishes."""
    configs = tiny_configs(tmp_path / "configs", steps=4)
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "scene"}], [2],
                       models(configs, names=("DS-NeRF",)), configs, tmp_path / "out")
    plan = build_plan(load_sweep(path), path)
    fit = next(u for u in plan.units if u.stage == "fit")
    override = callbacks_override(tmp_path / "configs", "preempt", "RequeueSignalAt", step=2, keep_warmup=False)
    fit.args += ["--config", str(override)]
    for key, value in {"SLURM_NTASKS": "1", "SLURM_JOB_NAME": "tiny-fit", "SLURM_NODELIST": "localhost",
                       "SLURM_JOB_ID": "4243", "SLURM_ARRAY_JOB_ID": "4242", "SLURM_ARRAY_TASK_ID": "1",
                       "SLURM_PROCID": "0", "SLURM_LOCALID": "0", "SLURM_NODEID": "0"}.items():
        monkeypatch.setenv(key, value)
    handler = signal.getsignal(signal.SIGUSR1)
    with mock.patch("lightning.pytorch.trainer.connectors.signal_connector.call", return_value=0) as call:
        with pytest.raises(Preempted):
            run_unit(fit)
    assert signal.getsignal(signal.SIGUSR1) == handler
    call.assert_called_once_with(["scontrol", "requeue", "4242_1"])
    folder = Path(fit.folder)
    assert (folder / "hpc_ckpt_1.ckpt").is_file()
    state = read_state(folder, "fit")
    assert state["status"] == "failed" and state["job_id"] == "4242_1" and "Preempted" in state["error"]
    assert run_unit(fit) == "done"  # the requeued job
    state = read_state(folder, "fit")
    assert state["attempts"] == 2 and state["status"] == "done"
    assert torch.load(folder / "checkpoints" / "last.ckpt", weights_only=False)["global_step"] == 4
    started = sorted(p.name for p in (folder / "wandb").glob("offline-run-*"))
    assert len(started) == 2 and len({wandb_run_id(name) for name in started}) == 1
