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
from datetime import datetime
from pathlib import Path
from unittest import mock

import pytest
import torch
import yaml

from simplenerf.commands import main
from simplenerf.experiments.executors import submit_slurm, units_to_run
from simplenerf.experiments.jobs import JobFailed, run_unit
from simplenerf.experiments.plan import build_plan
from simplenerf.experiments.spec import SweepError, load_sweep
from simplenerf.experiments.state import read_state
from simplenerf.experiments.status import status_table
from tests import preloaded_cli
from tests.conftest import REPO
from tests.experiments.sweep_fixtures import (
    Preempted,
    callbacks_override,
    models,
    record_gpus,
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
    return preloaded_cli.run(["sweep", *args], cwd=cwd, env=env, timeout=600)


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
    # The table (afterany) ran: DS-NeRF's row, and a line for the run that is missing with its reason.
    results = (tmp_path / "out" / "results.md").read_text()
    assert "| DS-NeRF |" in results and "| SimpleNeRF |" not in results
    assert ("- 1 of 2 runs are not in the table (the means above are over the others):\n"
            "  - scene0/2v/SimpleNeRF/seed0: its fit stopped at step 2 (its process ended without a word: killed, out "
            "of memory?); its test did not run") in results
    step2 = simple / "checkpoints" / "step000002.ckpt"
    untouched = {p: p.stat().st_mtime_ns for p in [step2, *ds.rglob("*.ckpt"), ds / "test" / "summary.json"]}

    main(["sweep", "--config", str(path)])
    assert {p: p.stat().st_mtime_ns for p in untouched} == untouched  # not started over; the finished run untouched
    assert torch.load(simple / "checkpoints" / "last.ckpt", weights_only=False)["global_step"] == 6
    assert read_state(simple, "fit")["attempts"] == 2 and read_state(ds, "fit")["attempts"] == 1
    assert (simple / "test" / "summary.json").is_file()
    assert "| SimpleNeRF |" in (tmp_path / "out" / "results.md").read_text()


def test_a_failed_fit_blocks_its_own_test_only_and_the_table_says_why(tmp_path):
    """One fit raises at step 1: its test never starts (blocked), the other model's fit and test finish, the sweep
    ends with status 1 and the table has the finished row plus a line for the missing run with the fit's error."""
    configs = tiny_configs(tmp_path / "configs", steps=2)
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    fail = callbacks_override(tmp_path / "configs", "fail", "FailAt", step=1, keep_warmup=False)  # DS-NeRF: none
    model_list = models(configs)
    model_list[1]["configs"].append(str(fail))
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "scene"}], [2], model_list,
                       configs, tmp_path / "out")
    with pytest.raises(SystemExit) as ended:
        main(["sweep", "--config", str(path)])
    assert ended.value.code == 1
    runs = tmp_path / "out" / "runs" / "scene0" / "2v"
    assert (runs / "SimpleNeRF" / "seed0" / "test" / "summary.json").is_file()
    assert read_state(runs / "DS-NeRF" / "seed0", "fit")["status"] == "failed"
    assert read_state(runs / "DS-NeRF" / "seed0", "test") is None  # never started
    results = (tmp_path / "out" / "results.md").read_text()
    assert "| SimpleNeRF |" in results and "| DS-NeRF |" not in results
    assert ("  - scene0/2v/DS-NeRF/seed0: its fit failed: RuntimeError: made to fail at step 1; its test did not run"
            in results), results


@pytest.fixture
def table1_sweep(tmp_path) -> Path:
    """configs/sweeps/llff_table1.yaml with its output in tmp_path (its scenes need not exist for a dry run)."""
    sweep = yaml.safe_load((REPO / "configs" / "sweeps" / "llff_table1.yaml").read_text())
    sweep["output"] = str(tmp_path / "out")
    path = tmp_path / "llff_table1.yaml"
    path.write_text(yaml.safe_dump(sweep, sort_keys=False))
    return path


def fake_sbatch(bin_dir: Path) -> None:
    """A stand-in sbatch on PATH: records its arguments in bin/calls and answers job ids 1001, 1002, ..."""
    bin_dir.mkdir(exist_ok=True)
    (bin_dir / "sbatch").write_text('#!/bin/bash\nd=$(dirname "$0"); n=$(( $(cat "$d/n" 2>/dev/null || echo 1000) + 1'
                                    '))\necho $n > "$d/n"; echo "$@" >> "$d/calls"; echo "$n;cluster"\n')
    (bin_dir / "sbatch").chmod(0o755)


def waits_on(dependency: str | None, n_tasks: int) -> list[set[tuple[str, int | None]]]:
    """Per task of an array, the (job id, task) it waits for, as SLURM reads `--dependency`: `afterok:J` every task of
    J, `afterok:J_T` task T, `aftercorr:J` the task of the same index. (The table's afterany is left out.)"""
    per_task: list[set] = [set() for _ in range(n_tasks)]
    for part in (dependency or "").split(","):
        kind, _, targets = part.partition(":")
        if kind not in ("afterok", "aftercorr"):
            continue
        for target in targets.split(":"):
            job, _, task = target.partition("_")
            for i in range(n_tasks):
                per_task[i].add((job, i if kind == "aftercorr" else int(task) if task else None))
    return per_task


def test_slurm_dry_run_scripts_wait_per_task_and_ask_per_stage_resources(table1_sweep, tmp_path):
    """The dry run's scripts as a cluster admin reads them: each test waits for its own fit and its own masks only
    (a failed fit cancels its one test), depth task i after dense task i, the masks after their scene's depth, the
    table after every test whatever their outcome; the masks and the table ask for no GPU. submit.sh runs as it is
    (a stand-in sbatch) and records the job ids for `sweep status`."""
    proc = sweep_cli("--config", str(table1_sweep), "--executor", "slurm", "--dry_run")
    assert proc.returncode == 0, proc.stderr
    folder = tmp_path / "out" / "slurm"
    arrays = json.loads((folder / "arrays.json").read_text())
    names = [a["name"] for a in arrays]
    assert names == ["dense", "depth", *[f"masks_{k}" for k in range(8)], "fit", *[f"test_{k}" for k in range(48)],
                     "table"]
    fit = (folder / "fit.sbatch").read_text()
    for line in ("#SBATCH --array=0-47%24", "#SBATCH --signal=USR1@90", "#SBATCH --gpus-per-node=1",
                 "#SBATCH --cpus-per-task=8", "#SBATCH --mem=32768MB", "#SBATCH --time=1440",
                 "#SBATCH --kill-on-invalid-dep=yes", f"#SBATCH --chdir={REPO}", "-m simplenerf sweep job",
                 " fit ${SLURM_ARRAY_TASK_ID}", "srun "):
        assert line in fit, line
    for name in ("masks_0", "table"):  # no GPU where none is used
        assert "--gpus" not in (folder / f"{name}.sbatch").read_text() and "--gres" not in (
            folder / f"{name}.sbatch").read_text(), name
    table = (folder / "table.sbatch").read_text()
    assert "#SBATCH --cpus-per-task=1" in table and "#SBATCH --time=30" in table and "#SBATCH --mem=4096MB" in table
    assert "#SBATCH --gpus-per-node=1" in (folder / "test_0.sbatch").read_text()

    # submit.sh as it is, with a stand-in sbatch
    fake_sbatch(tmp_path / "bin")
    path = f"{tmp_path / 'bin'}:{os.environ['PATH']}"
    run = subprocess.run(["bash", str(folder / "submit.sh")], env={**os.environ, "PATH": path}, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr
    calls = (tmp_path / "bin" / "calls").read_text().splitlines()
    assert [Path(c.split()[-1]).stem for c in calls] == names
    ids = {name: str(1001 + i) for i, name in enumerate(names)}
    assert (folder / "submitted.txt").read_text().splitlines() == [f"{n} {ids[n]}" for n in names]
    found = [re.search(r"--dependency=(\S+)", c) for c in calls]
    dependency = {n: m[1] if m else None for n, m in zip(names, found, strict=True)}
    assert dependency["dense"] is None and dependency["fit"] is None
    assert dependency["depth"] == f"aftercorr:{ids['dense']}"
    assert dependency["table"] == "afterany:" + ":".join(ids[f"test_{k}"] for k in range(48))

    # Unit ids per (job id, task), then what every task waits for: exactly the units it reads.
    unit_at = {(ids[a["name"]], t): u for a in arrays for t, u in enumerate(a["units"])}
    units = {u.id: u for u in build_plan(load_sweep(table1_sweep), table1_sweep, check_scenes=False).units}
    readers: dict[str, set[str]] = {}
    for a in arrays:
        if a["name"] == "table":
            continue
        for task, waits in enumerate(waits_on(dependency[a["name"]], len(a["units"]))):
            unit = a["units"][task]
            read = {unit_at[(j, t)] for j, t in waits if t is not None}
            read |= {u for j, t in waits if t is None for (jj, _), u in unit_at.items() if jj == j}
            assert read == set(units[unit].needs), (unit, read)
            for r in read:
                readers.setdefault(r, set()).add(unit)
    fit_units = json.loads((folder / "fit.json").read_text())
    assert len(fit_units) == 48
    for fit_unit in fit_units:  # a failed fit blocks its own test and nothing else
        assert readers[f"fit:{fit_unit['key']}"] == {f"test:{fit_unit['key']}"}
    assert readers["masks:fern/2v"] == {f"test:fern/2v/{m}/seed0" for m in ("SimpleNeRF", "DS-NeRF")}
    assert readers["depth:fern"] == {f"masks:fern/{n}v" for n in (2, 3, 4)}


def names_index(arrays: list[dict], name: str) -> int:
    return [a["name"] for a in arrays].index(name)


def test_slurm_submission_through_submitit(table1_sweep, tmp_path, monkeypatch):
    """The real path: submitit writes and submits each array (here to a stand-in sbatch), the per-task dependencies
    and Lightning's requeue signal in the scripts; submitit's own preemption signal is not the one SLURM sends."""
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
    assert list(ids)[:4] == ["dense", "depth", "masks_0", "masks_1"] and len(ids) == 2 + 8 + 1 + 48 + 1
    scripts = {p.name: p.read_text() for p in bin_dir.glob("*.sh")}
    arrays = json.loads((tmp_path / "out" / "slurm" / "arrays.json").read_text())
    at = {u: (a["name"], t) for a in arrays for t, u in enumerate(a["units"])}
    test_unit = next(u for u in plan.units if u.id == arrays[names_index(arrays, "test_5")]["units"][0])
    masks, fit = (at[n] for n in sorted(test_unit.needs, key=lambda n: n.startswith("fit")))
    test = scripts[f"{ids['test_5']}.sh"]
    assert f"#SBATCH --dependency=afterok:{ids[masks[0]]}_{masks[1]}:{ids['fit']}_{fit[1]}" in test
    assert f"#SBATCH --dependency=aftercorr:{ids['dense']}" in scripts[f"{ids['depth']}.sh"]
    assert "#SBATCH --signal=USR1@90" in test and "submitit.core._submit" in test
    assert "--gpus-per-node" not in scripts[f"{ids['masks_0']}.sh"] and "--gpus-per-node=1" in test
    submitted = (tmp_path / "out" / "slurm" / "submitted.txt").read_text().splitlines()
    assert submitted == [f"{name} {i}" for name, i in ids.items()]
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


def test_each_job_runs_with_cpus_per_job_threads(tmp_path, monkeypatch):
    """A job's torch threads are its stage's `cpus_per_job` (as SLURM's --cpus-per-task bounds it): locally,
    `concurrent_jobs` jobs of all-cores threads each would fight for the cores. The sweep's own process (debug
    executor) gets its thread count back afterwards, also when the job fails."""
    configs = tiny_configs(tmp_path / "configs", steps=4)
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "scene"}], [2],
                       models(configs, names=("DS-NeRF",)), configs, tmp_path / "out",
                       resources={"cpus_per_job": 3, "stages": {"test": {"cpus_per_job": 2}}})
    plan = build_plan(load_sweep(path), path)
    assert {u.stage: u.extra["cpus"] for u in plan.units} == {"masks": 3, "fit": 3, "test": 2, "table": 1}
    seen = []

    def record(unit):
        seen.append(torch.get_num_threads())
        if unit.stage == "test":
            raise JobFailed("no checkpoint")

    from simplenerf.experiments import jobs

    monkeypatch.setitem(jobs.STAGE_FUNCTIONS, "fit", record)
    monkeypatch.setitem(jobs.STAGE_FUNCTIONS, "test", record)
    before = torch.get_num_threads()
    assert run_unit(next(u for u in plan.units if u.stage == "fit")) == "done"
    assert torch.get_num_threads() == before
    with pytest.raises(JobFailed):
        run_unit(next(u for u in plan.units if u.stage == "test"))
    assert seen == [3, 2] and torch.get_num_threads() == before


def fake_slurm_tool(bin_dir: Path, name: str, output: str) -> None:
    """A stand-in SLURM command on PATH: records its arguments in bin/<name>.calls and prints `output`."""
    (bin_dir / name).write_text(f'#!/bin/bash\nprintf "%s\\n" "$*" >> "$(dirname "$0")/{name}.calls"\n'
                                f'cat <<"EOF"\n{output}EOF\n')
    (bin_dir / name).chmod(0o755)


def test_status_asks_slurm_and_cancel_cancels_what_is_queued_or_running(table1_sweep, tmp_path):
    """A submitted sweep (the dry run's submit.sh with a stand-in sbatch: arrays 1001, 1002, ...), then stand-in
    squeue / sacct: what SLURM killed shows with its state and job id, what waits shows queued; `sweep cancel` sends
    scancel the arrays that still have something queued or running."""
    assert sweep_cli("--config", str(table1_sweep), "--executor", "slurm", "--dry_run").returncode == 0
    out = tmp_path / "out"
    bin_dir = tmp_path / "bin"
    fake_sbatch(bin_dir)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}"}
    assert subprocess.run(["bash", str(out / "slurm" / "submit.sh")], env=env, capture_output=True).returncode == 0
    submitted = dict(line.split() for line in (out / "slurm" / "submitted.txt").read_text().splitlines())
    fit, test0 = submitted["fit"], submitted["test_0"]
    fits = [u["key"] for u in json.loads((out / "slurm" / "fit.json").read_text())]
    fake_slurm_tool(bin_dir, "sacct", f"{submitted['dense']}_0|COMPLETED|0:0\n{fit}_2|TIMEOUT|0:0\n"
                    f"{fit}_3|OUT_OF_MEMORY|0:125\n{fit}_4|NODE_FAIL|0:0\n{fit}_5|CANCELLED by 1000|0:0\n")
    fake_slurm_tool(bin_dir, "squeue", f"{fit}_0|RUNNING|None\n{fit}_[6-47%24]|PENDING|JobArrayTaskLimit\n"
                    f"{test0}_0|PENDING|Dependency\n")
    fake_slurm_tool(bin_dir, "scancel", "")
    status = preloaded_cli.run(["sweep", "status", str(out)], cwd=REPO, env=env)
    assert status.returncode == 0, status.stderr
    rows = {tuple(c.strip() for c in line.split("|")[1:6]): [c.strip() for c in line.split("|")[6:-1]]
            for line in status.stdout.splitlines() if line.startswith("| fit") or line.startswith("| test")}

    def row(stage: str, key: str) -> list[str]:
        scene, views, model, seed = key.split("/")
        return rows[(stage, scene, views.removesuffix("v"), model, seed.removeprefix("seed"))]

    assert row("fit", fits[0])[0] == "running" and row("fit", fits[0])[3] == f"{fit}_0"
    for task, state in ((2, "timeout"), (3, "out_of_memory"), (4, "node_fail"), (5, "cancelled")):
        status_, _, _, job, error = row("fit", fits[task])
        assert (status_, job) == (state, f"{fit}_{task}") and error.startswith(f"SLURM: {state.upper()}"), task
    assert row("fit", fits[3])[4] == "SLURM: OUT_OF_MEMORY, exit 0:125"
    assert row("fit", fits[47])[0] == "queued" and row("fit", fits[47])[4] == "SLURM: PENDING (JobArrayTaskLimit)"
    assert row("test", fits[0])[0] == "queued" and row("test", fits[0])[3] == f"{test0}_0"
    assert row("fit", fits[1])[0] == "pending"  # SLURM knows nothing of it: the sweep's own word
    assert (bin_dir / "sacct.calls").read_text().startswith("-n -P -X -j 1001,1002,")

    cancel = preloaded_cli.run(["sweep", "cancel", str(out)], cwd=REPO, env=env)
    assert cancel.returncode == 0, cancel.stderr
    assert (bin_dir / "scancel.calls").read_text().split() == [fit, test0]
    assert f"cancelled 2 of {len(submitted)} job arrays: {fit} {test0}" in cancel.stdout


def test_preflight_lists_every_problem_and_submits_nothing(tmp_path):
    """A SLURM sweep whose scene lacks its poses file, whose tests need LPIPS weights that are not there, with no W&B
    mode stated and an output under a file: one line per problem, exit status 2, no sbatch called, nothing written."""
    configs = tiny_configs(tmp_path / "configs")
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    (scene / "poses_bounds.npy").unlink()
    lpips = tmp_path / "configs" / "lpips.yaml"
    lpips.write_text(yaml.safe_dump({"evaluation": {"lpips": True, "lpips_weights": str(tmp_path / "no.npz")}}))
    model_list = models(configs, names=("SimpleNeRF",))
    model_list[0]["configs"].append(str(lpips))
    (tmp_path / "a_file").write_text("")
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "scene"}], [2], model_list,
                       configs, tmp_path / "a_file" / "out", executor="slurm")
    fake_sbatch(tmp_path / "bin")
    env = {k: v for k, v in os.environ.items() if k != "WANDB_MODE"}
    env.update(PATH=f"{tmp_path / 'bin'}:{os.environ['PATH']}", OMP_NUM_THREADS="1")
    proc = preloaded_cli.run(["sweep", "--config", str(path)], cwd=REPO, env=env, timeout=600)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[0] == "simplenerf: error: 6 problem(s) found before anything ran; nothing was submitted:", lines
    assert lines[1] == f"  scenes[0] (scene0): {scene / 'poses_bounds.npy'} is missing or not readable (llff scenes " \
                       "have it)"
    assert lines[2].startswith(f"  LPIPS weights (--evaluation.lpips_weights {tmp_path / 'no.npz'}) cannot be found "
                               "without network, as test scene0/2v/SimpleNeRF/seed0 needs them")
    assert lines[3].startswith("  W&B mode not stated: set wandb.mode in the sweep file")
    assert lines[4] == f"  output {tmp_path / 'a_file' / 'out'}: {tmp_path / 'a_file'} is a file, not a folder"
    assert lines[5].startswith(f"  {tmp_path / 'a_file' / 'out'} is on this machine's own disk (/tmp)")
    assert len(lines) == 7 and lines[6].startswith(f"  {scene} is on this machine's own disk"), lines
    assert not (tmp_path / "bin" / "calls").exists()  # nothing submitted


def test_local_executor_gives_each_concurrent_job_its_own_gpu(tmp_path, monkeypatch):
    """A machine with 2 GPUs (torch's device count faked), 3 jobs at a time, 1 GPU per fit: no two fits running at
    once share a GPU, so at most 2 run together; a masks job (no GPU) sees none."""
    from simplenerf.experiments.executors import run_here
    from simplenerf.experiments.plan import Plan, Unit
    from simplenerf.experiments.spec import Resources, Sweep

    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    sweep = Sweep(name="gpus", output=str(tmp_path), scenes=[], views=[2], models=[],
                  resources=Resources(gpus_per_job=1, concurrent_jobs=3))
    units = [Unit("fit", f"run{i}", str(tmp_path / f"run{i}"), "d") for i in range(5)]
    units.append(Unit("masks", "m", str(tmp_path / "masks"), "d"))
    outcome = run_here(Plan(sweep, tmp_path, units), units, "local", log=lambda *a: None,
                       job_function=record_gpus)
    assert set(outcome.values()) == {"done"}
    runs = [json.loads((tmp_path / f"run{i}" / "gpus.json").read_text()) for i in range(5)]
    assert all(r["cuda"] in ("0", "1") for r in runs), runs
    for i, a in enumerate(runs):
        for b in runs[i + 1 :]:
            if a["start"] < b["end"] and b["start"] < a["end"]:
                assert a["cuda"] != b["cuda"], (a, b)
    assert {r["cuda"] for r in runs} == {"0", "1"}
    assert json.loads((tmp_path / "masks" / "gpus.json").read_text())["cuda"] == ""


def test_local_executor_refuses_more_gpus_per_job_than_the_machine_has(tmp_path, monkeypatch):
    from simplenerf.experiments.executors import run_here
    from simplenerf.experiments.plan import Plan, Unit
    from simplenerf.experiments.spec import Resources, Sweep

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")  # two GPUs handed to this sweep
    sweep = Sweep(name="gpus", output=str(tmp_path), scenes=[], views=[2], models=[],
                  resources=Resources(gpus_per_job=1, stages={"fit": {"gpus_per_job": 4}}))
    units = [Unit("fit", "run", str(tmp_path / "run"), "d")]
    with pytest.raises(SweepError, match=r"the fit jobs ask for 4 GPUs each; this machine has 2 \(3, 5\)"):
        run_here(Plan(sweep, tmp_path, units), units, "local", log=lambda *a: None, job_function=record_gpus)


def test_resources_per_stage_from_the_sweep_file(tmp_path):
    """The sweep's resources are the GPU stages'; the masks and the table default to no GPU (the table: 1 CPU, 4 GB,
    30 min); `resources.stages` overrides any stage, its slurm_args added to the sweep's; a wrong stage name stops."""
    text = ("name: x\noutput: out\nscenes: [{path: a}]\nviews: [2]\nmodels: [{name: A, configs: [a.yaml]}]\n"
            "resources:\n  gpus_per_job: 1\n  mem_gb: 32\n  slurm_args: {qos: high}\n  stages:\n"
            "    masks: {partition: cpu, cpus_per_job: 4}\n"
            "    fit: {time_limit_min: 720, slurm_args: {constraint: a100}}\n")
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    resources = load_sweep(path).resources
    masks, fit, table, test = (resources.for_stage(s) for s in ("masks", "fit", "table", "test"))
    assert (masks.gpus_per_job, masks.cpus_per_job, masks.partition, masks.mem_gb) == (0, 4, "cpu", 32)
    assert (fit.gpus_per_job, fit.time_limit_min, fit.slurm_args) == (1, 720, {"qos": "high", "constraint": "a100"})
    assert (table.gpus_per_job, table.cpus_per_job, table.mem_gb, table.time_limit_min) == (0, 1, 4, 30)
    assert (test.gpus_per_job, test.time_limit_min, test.slurm_args) == (1, 60, {"qos": "high"})
    path.write_text(text.replace("    masks:", "    maks:"))
    with pytest.raises(SweepError, match=r"resources\.stages: 'maks' is not a stage \(dense, depth, masks, fit"):
        load_sweep(path)


def test_a_sweep_reuses_the_fits_another_sweep_has(tmp_path):
    """Sweep A trains SimpleNeRF; sweep B (SimpleNeRF and DS-NeRF, `reuse: [A's output]`) links A's SimpleNeRF fit
    (same settings digest) instead of training it, tests it into its own folder, and trains only DS-NeRF."""
    configs = tiny_configs(tmp_path / "configs", steps=2)
    scene = synthetic_scenes(tmp_path / "data", n=1)[0]
    scenes = [{"path": str(scene), "reference_depth": "scene"}]
    a = write_sweep(tmp_path / "a.yaml", scenes, [2], models(configs, names=("SimpleNeRF",)), configs, tmp_path / "a")
    main(["sweep", "--config", str(a)])
    a_run = tmp_path / "a" / "runs" / "scene0" / "2v" / "SimpleNeRF" / "seed0"
    a_ckpts = {p: p.stat().st_mtime_ns for p in (a_run / "checkpoints").glob("*.ckpt")}
    a_summary = (a_run / "test" / "summary.json").stat().st_mtime_ns
    b = write_sweep(tmp_path / "b.yaml", scenes, [2], models(configs), configs, tmp_path / "b",
                    reuse=[str(tmp_path / "a")])
    plan = build_plan(load_sweep(b), b)
    assert [u.id for u in units_to_run(plan) if u.stage == "fit"] == ["fit:scene0/2v/SimpleNeRF/seed0",
                                                                      "fit:scene0/2v/DS-NeRF/seed0"]
    main(["sweep", "--config", str(b)])
    b_run = tmp_path / "b" / "runs" / "scene0" / "2v" / "SimpleNeRF" / "seed0"
    assert (b_run / "checkpoints").resolve() == (a_run / "checkpoints").resolve()
    assert read_state(b_run, "fit")["reused_from"] == str(a_run.resolve())
    assert (b_run / "test" / "summary.json").is_file()  # tested here
    assert {p: p.stat().st_mtime_ns for p in (a_run / "checkpoints").glob("*.ckpt")} == a_ckpts  # not retrained
    assert (a_run / "test" / "summary.json").stat().st_mtime_ns == a_summary  # A's folder only read
    assert read_state(tmp_path / "b" / "runs" / "scene0" / "2v" / "DS-NeRF" / "seed0", "fit")["status"] == "done"
    assert "| SimpleNeRF |" in (tmp_path / "b" / "results.md").read_text()


def test_the_ablations_sweep_reuses_the_13_simplenerf_fits_of_table1(monkeypatch):
    """configs/sweeps/ablations_table3.yaml names the Table 1 sweeps in `reuse`, and its SimpleNeRF fits have the
    settings digests of Table 1's 2-view SimpleNeRF fits (8 LLFF scenes + 5 videos): they would be linked."""
    monkeypatch.chdir(REPO)
    digests = {}
    for name in ("llff_table1", "realestate_table1", "ablations_table3"):
        path = REPO / "configs" / "sweeps" / f"{name}.yaml"
        sweep = load_sweep(path)
        digests[name] = {u.digest: u.key for u in build_plan(sweep, path, check_scenes=False).stage("fit")}
    assert sweep.reuse == ["runs/sweeps/llff_table1", "runs/sweeps/realestate_table1"]
    table1 = digests["llff_table1"].keys() | digests["realestate_table1"].keys()
    shared = sorted(key for digest, key in digests["ablations_table3"].items() if digest in table1)
    assert len(shared) == 13 and all(key.endswith("/2v/SimpleNeRF/seed0") for key in shared)


def test_local_slots_go_to_units_in_the_order_they_became_ready():
    """One slot: a unit that becomes ready when the running job ends (its test) does not take the freed slot ahead of
    the unit already waiting for it (the next fit), as a semaphore lets it."""
    import threading
    import time

    from simplenerf.experiments.slots import ReadySlots

    slots, started = ReadySlots(1), []

    def fit_then_its_test() -> None:
        with slots.slot(0):
            started.append("fit 0")
            while not slots.waiting:  # fit 1 waits for the slot
                time.sleep(0.001)
        with slots.slot(2):  # ready now that fit 0 is done
            started.append("test 0")

    def next_fit() -> None:
        while not started:
            time.sleep(0.001)
        with slots.slot(1):
            started.append("fit 1")

    threads = [threading.Thread(target=fit_then_its_test), threading.Thread(target=next_fit)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10)
    assert started == ["fit 0", "fit 1", "test 0"]
    assert slots.free == 1 and slots.finished == 3 and not slots.waiting
