"""Nothing lost, nothing mistaken for finished (issue 23), through the real command line: signals stop a run with a
resumable checkpoint and a non-zero exit status (docs/running.md), one writer per run folder, a resume continues the
run (same losses as a straight run) and refuses other settings, counts are checked where declared, process-data never
writes into its input, and the last tracebacks are one line each. Signals are sent to a child process."""

from __future__ import annotations

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from simplenerf.sfm.process_checks import MARKER, judge
from tests.run.test_cli import REPO, run, run_args

ERROR = "simplenerf: error: "
# No validation or numbered checkpoint in the way, a progress line every step.
LONG = ["--trainer.max_steps", "100000", "--trainer.val_check_interval", "100000", "--checkpoint.every_n_train_steps",
        "100000", "--progress.every_n_steps", "1"]


def env() -> dict:
    return {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true", "PYTHONUNBUFFERED": "1"}


def start(tmp: Path, *args: str, command: list[str] | None = None) -> subprocess.Popen:
    """`python -m simplenerf ARGS` as a child process; stdout piped line by line, stderr into tmp/stderr-<pid>."""
    stderr = open(tmp / f"stderr-{len(list(tmp.glob('stderr-*')))}", "w+")  # noqa: SIM115 (closed by finish)
    proc = subprocess.Popen([*(command or []), sys.executable, "-m", "simplenerf", *args], cwd=REPO, env=env(),
                            stdout=subprocess.PIPE, stderr=stderr, text=True)
    proc.stderr_file = stderr
    return proc


def wait_for(proc: subprocess.Popen, text: str) -> list[str]:
    """Reads the child's stdout up to the first line that starts with `text`; fails if it exits first."""
    seen = []
    for line in proc.stdout:
        seen.append(line.rstrip("\n"))
        if line.startswith(text):
            return seen
    raise AssertionError(f"exited ({proc.wait()}) before printing {text!r}:\n" + "\n".join(seen[-20:])
                         + "\n" + finish(proc)[1])


def finish(proc: subprocess.Popen, timeout: float = 120) -> tuple[int, str]:
    """The child's exit status and stderr, once it has exited."""
    proc.stdout.read()
    status = proc.wait(timeout)
    proc.stderr_file.seek(0)
    text = proc.stderr_file.read()
    proc.stderr_file.close()
    return status, text


def last_step(path: Path) -> int:
    return int(torch.load(path, map_location="cpu", weights_only=False)["global_step"])


def without_privileges(command: list[str]) -> list[str]:
    """`command` run so that file permissions hold for it (root gives up overriding them), or skip."""
    if os.geteuid() != 0:
        return command
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: permissions cannot be made to hold")
    caps = "-dac_override,-fowner"
    return ["setpriv", f"--bounding-set={caps}", f"--inh-caps={caps}", *command]


def run_unprivileged(*args: str) -> subprocess.CompletedProcess:
    command = without_privileges([sys.executable, "-m", "simplenerf", *args])
    return subprocess.run(command, cwd=REPO, env=env(), capture_output=True, text=True, timeout=600)


# ----------------------------------------------------------------------------------------------------------------
# Signals and the run folder's lock


def test_sigterm_and_sigint_stop_fit_with_a_checkpoint_and_a_busy_folder_is_refused(tmp_path):
    args = [*run_args(tmp_path), *LONG]
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    fit = start(tmp_path, "fit", *args)
    wait_for(fit, "step 3/")
    # | a second fit into a busy run folder | one line naming the other process |
    busy = run("fit", *args, check=False)
    assert busy.returncode == 2
    [line] = busy.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}the run folder {tmp_path / 'run'} is in use by pid {fit.pid} on ")
    assert " simplenerf fit --config configs/demo.yaml" in line and line.endswith(
        "; wait for it to finish, or use another --trainer.default_root_dir")
    # | SIGTERM during fit (a scheduler's stop) | last.ckpt at the end of the step, exit status 143 |
    fit.send_signal(signal.SIGTERM)
    status, stderr = finish(fit)
    step = last_step(last)
    assert status == 143 and step >= 3
    assert stderr.strip().splitlines()[-1] == (
        f"{ERROR}fit stopped by SIGTERM at step {step}; the checkpoints written before it are kept (resume from "
        f"{last}, step {step})")
    assert "Traceback" not in stderr
    # | Ctrl-C during a resumed fit | the same, exit status 130; the lock of the killed process is no obstacle |
    fit = start(tmp_path, "fit", *args, "--ckpt_path", "last")
    wait_for(fit, f"step {step + 2}/")
    # | `fit --overwrite true` and `test` into the running fit's folder | refused before anything there is touched |
    saved = {p.name: p.read_bytes() for p in last.parent.iterdir()}
    for verb, extra in (("fit", ["--overwrite", "true"]), ("test", ["--ckpt_path", "last"])):
        busy = run(verb, *args, *extra, check=False)
        assert busy.returncode == 2
        [line] = busy.stderr.strip().splitlines()
        assert line.startswith(f"{ERROR}the run folder {tmp_path / 'run'} is in use by pid {fit.pid} on ")
    assert {p.name: p.read_bytes() for p in last.parent.iterdir()} == saved
    fit.send_signal(signal.SIGINT)
    status, stderr = finish(fit)
    assert status == 130 and last_step(last) >= step + 2
    assert stderr.strip().splitlines()[-1].startswith(f"{ERROR}fit stopped by SIGINT at step {last_step(last)}; ")


def test_importing_pycolmap_keeps_the_python_sigterm_handler():
    """COLMAP's glog installs a SIGTERM handler at import that prints a native stack dump (`simplenerf sweep` imports
    pycolmap after its handlers are set): `simplenerf.sfm` sets the Python handler again."""
    code = ("import os, signal, sys\n"
            "def stop(signum, frame):\n    sys.exit(3)\n"
            "signal.signal(signal.SIGTERM, stop)\n"
            "import simplenerf.sfm.colmap\n"
            "os.kill(os.getpid(), signal.SIGTERM)\n"
            "import time; time.sleep(10)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3 and "SIGTERM" not in proc.stderr, proc.stderr[-2000:]


def test_a_lock_left_by_a_killed_process_is_taken_over(tmp_path):
    """SIGKILL leaves the lock file but not the lock: the kernel releases it with the process."""
    from simplenerf.errors import RunFolderError
    from simplenerf.run.lock import LOCK_NAME, lock_run_folder

    code = (f"from simplenerf.run.lock import lock_run_folder; lock_run_folder({str(tmp_path)!r}, 'holder'); "
            "print('locked', flush=True); import time; time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "locked"
    with pytest.raises(RunFolderError, match=rf"in use by pid {holder.pid} on .*: holder; wait for it"):
        lock_run_folder(tmp_path, "second")
    holder.kill()
    holder.wait()
    lock_run_folder(tmp_path, "second")  # taken over
    assert json.loads((tmp_path / LOCK_NAME).read_text())["command"] == "second"


def test_tools_do_not_write_into_a_run_in_use(resumed, tmp_path):
    """render-video, export-geometry and visibility-masks write into the run folder by default: not while another
    process holds its lock (a fit, a test), and nothing of theirs is written there."""
    run_dir = tmp_path / "run"
    shutil.copytree(resumed / "run" / "checkpoints", run_dir / "checkpoints")
    shutil.copyfile(resumed / "run" / "config.yaml", run_dir / "config.yaml")  # read where it is: tmp_path/run
    code = (f"from simplenerf.run.lock import lock_run_folder; lock_run_folder({str(run_dir)!r}, 'simplenerf fit'); "
            "print('locked', flush=True); import time; time.sleep(600)")
    config, ckpt = ["--config", str(run_dir / "config.yaml")], ["--ckpt", str(run_dir / "checkpoints" / "last.ckpt")]
    holder = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = sorted(p.name for p in run_dir.iterdir())
        for tool in (["render-video", *config, *ckpt, "--frames", "2", "--scale", "0.25"],
                     ["export-geometry", *config, *ckpt], ["visibility-masks", *config]):
            proc = run(*tool, check=False)
            assert proc.returncode == 2, proc.stderr[-2000:]
            line = proc.stderr.strip().splitlines()[-1]
            assert line.startswith(f"{ERROR}the run folder {run_dir} is in use by pid {holder.pid} on "), line
            assert line.endswith(": simplenerf fit; wait for it to finish, or write elsewhere with --out"), line
            assert "Traceback" not in proc.stderr
        assert sorted(p.name for p in run_dir.iterdir()) == before
    finally:
        holder.kill()
        holder.wait()
    run("visibility-masks", *config)  # the lock was the only obstacle
    assert (run_dir / "visibility").is_dir()


def test_a_stopped_test_leaves_no_partial_results(resumed, tmp_path):
    """SIGTERM after the first of 3 test frames, while the test works on (120 s, as a frame on a slow CPU): it stops
    within seconds, exit status 143, earlier results kept, no test.partial."""
    run_dir = resumed / "run"
    earlier = run_dir / "test"
    earlier.mkdir(exist_ok=True)
    (earlier / "summary.json").write_text("earlier results")
    slow = ["--trainer.callbacks+=tests.custom_callbacks.SlowTest", "--trainer.callbacks.seconds", "120"]
    test = start(tmp_path, "test", *run_args(resumed), "--ckpt_path", "last", "--evaluation.lpips", "false", *slow)
    wait_for(test, "frame 0 done")
    sent = time.monotonic()
    test.send_signal(signal.SIGTERM)
    status, stderr = finish(test)
    assert status == 143 and time.monotonic() - sent < 30
    assert stderr.strip().splitlines()[-1] == (
        f"{ERROR}test stopped by SIGTERM before it finished: no results were written (earlier results are kept)")
    assert (earlier / "summary.json").read_text() == "earlier results"
    assert not (run_dir / "test.partial").exists()


# ----------------------------------------------------------------------------------------------------------------
# Resume


@pytest.fixture(scope="module")
def resumed(tmp_path_factory) -> Path:
    """4 steps, then resumed to 8 (`run/`), and 8 steps straight (`straight/run`), each step's loss logged."""
    tmp = tmp_path_factory.mktemp("resume")
    log = ["--trainer.callbacks+=tests.custom_callbacks.LossLog", "--trainer.callbacks.path"]
    run("fit", *run_args(tmp), "--trainer.max_steps", "4", *log, str(tmp / "resumed.txt"))
    run("fit", *run_args(tmp), "--trainer.max_steps", "8", "--ckpt_path", "last", *log, str(tmp / "resumed.txt"))
    run("fit", *run_args(tmp / "straight", tmp), "--trainer.max_steps", "8", *log, str(tmp / "straight.txt"))
    return tmp


def test_a_resumed_run_has_the_losses_of_a_straight_run(resumed):
    """Data order, random state (also across the validations at steps 2, 4, 6) and the LR and loss-weight
    schedules continue: 4 steps + 4 resumed give the 8 losses of a straight run, to the bit here (same machine)."""
    def read(name: str) -> tuple[list[int], list[float]]:
        rows = [line.split() for line in (resumed / name).read_text().splitlines()]
        return [int(step) for step, _ in rows], [float.fromhex(loss) for _, loss in rows]

    (steps, losses), (straight_steps, straight) = read("resumed.txt"), read("straight.txt")
    assert steps == straight_steps == list(range(1, 9))
    assert losses == pytest.approx(straight, rel=1e-6, abs=0)


def test_a_resume_or_test_with_other_settings_stops_unless_allowed(resumed):
    run_dir = resumed / "run"
    last = run_dir / "checkpoints" / "last.ckpt"
    config = (run_dir / "config.yaml").read_bytes()
    proc = run("fit", *run_args(resumed), "--trainer.max_steps", "10", "--ckpt_path", "last",
               "--data.init_args.n_views", "2", check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}this resume differs from the run of checkpoint {last} (step 8) in data.n_views: "
                           "3 -> 2; train_frames: [")
    assert line.endswith("; use the run's settings (its config.yaml), start a new run in another folder, or accept "
                         "the change with --allow_changes [data.n_views, train_frames]")
    assert (run_dir / "config.yaml").read_bytes() == config and last_step(last) == 8
    # Allowed explicitly: resumed (max_steps 8 is reached already, so nothing trains).
    run("fit", *run_args(resumed), "--trainer.max_steps", "8", "--ckpt_path", "last", "--data.init_args.rays_per_batch",
        "32", "--allow_changes", "[data.init_args.rays_per_batch]")
    # | test of a run whose config names another scene | one line |
    proc = run("test", *run_args(resumed), "--ckpt_path", "last", "--evaluation.lpips", "false",
               "--data.init_args.scene_seed", "1", check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}this test differs from the run of checkpoint {last} (step 8) in scene.scene: ")
    assert f"seed0_96x128_20 -> {resumed / 'data' / 'seed1_96x128_20'}; " in line


def test_a_copied_runs_config_tests_the_copy(resumed, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(resumed / "run" / "checkpoints", copy / "checkpoints")
    shutil.copyfile(resumed / "run" / "config.yaml", copy / "config.yaml")
    before = sorted(p.name for p in (resumed / "run").iterdir())
    proc = run("test", "--config", str(copy / "config.yaml"), "--ckpt_path", "last", "--evaluation.lpips", "false")
    assert (f"simplenerf: {copy / 'config.yaml'} is the config of a run trained in {resumed / 'run'}; using the run "
            f"where the file is, {copy}") in proc.stderr.splitlines()
    assert json.loads((copy / "test" / "summary.json").read_text())["checkpoint"].startswith(str(copy))
    assert sorted(p.name for p in (resumed / "run").iterdir()) == before  # the original is not touched


def test_a_resume_compares_the_scene_by_its_content_not_its_folder(resumed, tmp_path):
    """The run's scene copied to another folder resumes, said in one line; other poses there stop the resume; a
    checkpoint recorded before the scene's digest compares the folder, as it did."""
    from simplenerf.run.resume import RECORD_KEY

    scene = "seed0_96x128_20"
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    shutil.copytree(resumed / "run" / "checkpoints", last.parent)
    shutil.copytree(resumed / "data" / scene, tmp_path / "data" / scene)  # run_args(tmp_path) reads tmp_path/data
    # | the scene in another folder | resumed, one line naming both folders |
    proc = run("fit", *run_args(tmp_path), "--trainer.max_steps", "9", "--ckpt_path", "last")
    assert (f"simplenerf: scene folder moved: {resumed / 'data' / scene} -> {tmp_path / 'data' / scene} (the same "
            "image names and poses); resuming the run there") in proc.stderr.splitlines()
    assert last_step(last) == 9
    # | a checkpoint from before the digest | the folder is compared: another folder stops, the same resumes |
    checkpoint = torch.load(last, map_location="cpu", weights_only=False)
    digest = checkpoint[RECORD_KEY]["settings"].pop("scene_digest")
    torch.save(checkpoint, last)
    args = [a.replace(str(tmp_path / "data"), str(resumed / "data")) for a in run_args(tmp_path)]
    proc = run("fit", *args, "--trainer.max_steps", "9", "--ckpt_path", "last", check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}this resume differs from the run of checkpoint {last} (step 9) in scene.scene: "
                           f"{tmp_path / 'data' / scene} -> {resumed / 'data' / scene}; use the run's settings ")
    proc = run("fit", *run_args(tmp_path), "--trainer.max_steps", "9", "--ckpt_path", "last")
    assert "scene folder moved" not in proc.stderr and last_step(last) == 9
    # | other poses in the same folder | stopped, the line names the scene's content |
    torch.save(checkpoint | {RECORD_KEY: {**checkpoint[RECORD_KEY], "settings": {
        **checkpoint[RECORD_KEY]["settings"], "scene_digest": digest}}}, last)  # as it was written
    poses = np.load(tmp_path / "data" / scene / "poses_bounds.npy")
    poses[1, 3] += 0.05
    np.save(tmp_path / "data" / scene / "poses_bounds.npy", poses)
    proc = run("fit", *run_args(tmp_path), "--trainer.max_steps", "10", "--ckpt_path", "last", check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}this resume differs from the run of checkpoint {last} (step 9) in scene_digest: "
                           f"{digest} -> ")
    assert line.endswith(" (the scene's image names or poses are not those the run trained on); use the run's "
                         "settings (its config.yaml), start a new run in another folder, or accept the change with "
                         "--allow_changes [scene_digest]")
    assert last_step(last) == 9


# ----------------------------------------------------------------------------------------------------------------
# Numbers and parser errors


@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--data.init_args.rays_per_batch", "-64", "expected a positive integer, got -64"),
    ("--data.init_args.rays_per_batch", "0", "expected a positive integer, got 0"),
    ("--data.init_args.sparse_rays_per_batch", "-1", "expected an integer >= 0, got -1"),
])
def test_counts_must_be_positive(option, value, expected, tmp_path):
    proc = run("fit", "--config", "configs/demo.yaml", option, value, "--trainer.default_root_dir",
               str(tmp_path / "run"), check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[0] == (
        f"{ERROR}{option}: {expected} (simplenerf.data.synthetic.SyntheticDataModule)")
    assert not (tmp_path / "run").exists()


# Values that would fail inside Lightning or torch: one line naming the option, the value and what is allowed; no run
# folder. (The demo's scene, 3 train views of 128x96 = 36864 pixels, without sparse depth: no SfM.)
@pytest.mark.parametrize(("args", "expected"), [
    (["--data.init_args.rays_per_batch", "40000"], "--data.init_args.rays_per_batch: 40000 is more than the 36864 "
     "training pixels (3 train views of 128x96); use at most 36864"),
    (["--model.optimizer.init_args.lr", "-0.001"], "--model.optimizer (torch.optim.Adam): Invalid learning rate: "
     "-0.001"),
    (["--model.optimizer.init_args.betas", "[0.9, 1.5]"], "--model.optimizer (torch.optim.Adam): Invalid beta "
     "parameter at index 1: 1.5"),
    (["--model.lr_scheduler.init_args.decay_rate", "0"], "--model.lr_scheduler "
     "(simplenerf.method.optim.ExponentialDecay): decay_rate and decay_steps must be positive, got 0.0, 500"),
    (["--model.group_lr", "{other: -1}"], "--model.group_lr: the learning rate of group 'other' is -1.0; expected a "
     "number >= 0"),
    (["--model.group_lr", "{grid: 0.1}"], "--model.group_lr: group_lr names ['grid'], but the parameter groups are "
     "['mlp']"),
    (["--trainer.precision", "fp8"], "--trainer.precision: expected one of 64, 32, 16, transformer-engine, "
     "transformer-engine-float16, 16-true, 16-mixed, bf16-true, bf16-mixed, 32-true, 64-true, bf16, null; got fp8"),
    (["--viewer", "true", "--viewer_port", "99999"], "--viewer_port: expected a port number 0-65535, got 99999"),
    # Options manual optimisation does not honour, and abbreviations, which are not taken as the full name.
    *[(["--trainer." + option, value], f"--trainer.{option} {value}: SimpleNeRF optimises manually (one update per "
       f"step), which Lightning's {option} does not apply to; leave it unset (a larger --data.init_args.rays_per_batch"
       " with --model.rays_per_backward accumulates gradients over a batch's parts)")
      for option, value in (("gradient_clip_val", "0.5"), ("accumulate_grad_batches", "2"))],
    (["--optimizer", "torch.optim.SGD"], "unrecognized arguments: --optimizer torch.optim.SGD"),
    (["--trainer.max_step", "5"], "unrecognized arguments: --trainer.max_step 5"),
    # Lines that end with their cause: the class, the kind of path.
    (["--model.nerf.init_args.coarse.class_path", "simplenerf.model.fields.Nope"], "--model.nerf.init_args.coarse: "
     "class_path simplenerf.model.fields.Nope: module 'simplenerf.model.fields' has no attribute 'Nope'"),
    (["--data", "torch.nn.Linear"], "--data: class_path torch.nn.Linear: Import path does not correspond to a "
     "subclass of LightningDataModule"),
    (["--data", "simplenerf.data.llff.LLFFDataModule", "--data.init_args.scene_dir", "{tmp}/tiny_model.yaml"],
     "scene directory {tmp}/tiny_model.yaml is a file, not a folder"),
    (["--ckpt_path", "{tmp}"], "checkpoint {tmp} is a folder, not a file"),
])
def test_values_that_would_fail_inside_lightning_stop_at_the_command_line(args, expected, tmp_path):
    args = [arg.replace("{tmp}", str(tmp_path)) for arg in args]
    proc = run("fit", *run_args(tmp_path), "--data.init_args.sparse_rays_per_batch", "0", *args, check=False)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines()[0] == f"{ERROR}{expected.replace('{tmp}', str(tmp_path))}"
    assert "Traceback" not in proc.stderr and not (tmp_path / "run").exists()


def test_a_key_given_twice_in_a_config_is_one_line_naming_both(tmp_path):
    config = tmp_path / "twice.yaml"
    config.write_text("trainer:\n  max_steps: 3\n  val_check_interval: 2\n  max_steps: 4\n")
    proc = run("fit", "--config", "configs/demo.yaml", "--config", str(config), "--trainer.default_root_dir",
               str(tmp_path / "run"), check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"{ERROR}config file {config}: key 'max_steps' is given twice in one mapping, at line 2 and line 4 (the later "
        "would silently win); keep one"]
    assert not (tmp_path / "run").exists()
    # The optimiser is the model's: Lightning's own --optimizer / --lr_scheduler are not offered.
    help_text = run("fit", "--help").stdout
    assert "--model.optimizer" in help_text and "\n  --optimizer" not in help_text
    assert "\n  --lr_scheduler" not in help_text


def test_a_scene_folder_given_to_view_is_called_a_scene(synthetic_scene):
    proc = run("view", str(synthetic_scene), check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"{ERROR}{synthetic_scene} is a scene folder (poses_bounds.npy, images), not a run: view shows a trained run; "
        f"train one on it first (`simplenerf fit --config ... --data.init_args.scene_dir {synthetic_scene}`), then "
        "view its run folder"]


def llff_fit(scene: Path, tmp: Path, *extra: str) -> subprocess.CompletedProcess:
    """fit of the DS-NeRF config on the LLFF-layout `scene` at factor 1, train frames 0, 5, 10, run folder tmp/run."""
    return run("fit", "--config", "configs/dsnerf.yaml", "--data.init_args.scene_dir", str(scene),
               "--data.init_args.factor", "1", "--data.init_args.train_frames", "[0, 5, 10]",
               "--trainer.default_root_dir", str(tmp / "run"), "--trainer.logger", "false",
               "--data.init_args.sparse_depth_cache", str(tmp / "cache"), *extra, check=False)


def test_identical_train_images_and_sfm_failures_name_the_scenes_files(synthetic_scene, tmp_path):
    scene = Path(shutil.copytree(synthetic_scene, tmp_path / "scene"))
    # | a train image copied over another, sparse depth off | named before training |
    shutil.copyfile(scene / "images" / "000.png", scene / "images" / "005.png")
    proc = llff_fit(scene, tmp_path, "--data.init_args.sparse_rays_per_batch", "0")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"{ERROR}train images 000 and 005 of {scene} are identical or nearly (mean difference under 2/255): a "
        "NeRF needs views from different positions; check the scene's images (a copied file?), or choose other train "
        "frames (--data.init_args.train_frames)"]
    # | a blank train image, SfM for sparse depth | the scene's file is named, not COLMAP's temporary copy |
    shutil.copyfile(synthetic_scene / "images" / "005.png", scene / "images" / "005.png")
    blank = np.full((48, 64, 3), 128, np.uint8)
    assert cv2.imwrite(str(scene / "images" / "010.png"), blank)
    proc = llff_fit(scene, tmp_path)
    assert proc.returncode == 2
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith(f"{ERROR}image 2 (010) has no SIFT features: textureless "), line
    assert "0002.png" not in proc.stderr and not (tmp_path / "run").exists()


def test_fit_checks_the_lpips_weights_of_its_test_before_training(tmp_path):
    env = {"SIMPLENERF_LPIPS_WEIGHTS": str(tmp_path / "missing.npz"), "TORCH_HOME": str(tmp_path / "hub")}
    proc = run("fit", *run_args(tmp_path), "--data.init_args.sparse_rays_per_batch", "0", env=env, check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"{ERROR}the test of this run (--evaluation.lpips true) will need LPIPS weights, checked "
                           f"before training: SIMPLENERF_LPIPS_WEIGHTS={tmp_path / 'missing.npz'} does not name an "
                           "existing file.")
    assert "`--evaluation.lpips false`" in line and not (tmp_path / "run").exists()


def test_a_port_out_of_range_is_one_line(tmp_path):
    proc = run("view", str(tmp_path), "--port", "99999", check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[0] == (
        f"{ERROR}argument --port: expected a port number 0-65535 (0: any free one), got 99999")


def test_parser_errors_keep_their_cause(tmp_path):
    proc = run("fit", "--config", "configs/demo.yaml", "--model.chunk", "abc", check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[0] == f"{ERROR}--model.chunk: expected a positive integer, got 'abc'"
    bad = tmp_path / "bad.yaml"
    bad.write_text("trainer:\n  max_steps: 10\n  callbacks: [1\nmodel: {}\n")
    proc = run("fit", "--config", "configs/demo.yaml", "--config", str(bad), check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line == (f"{ERROR}config file {bad}: YAML syntax error at line 4, column 6: while parsing a flow sequence "
                    "expected ',' or ']', but got ':'")
    proc = run("fit", "--config", "configs/demo.yaml", "--trainer.max_steps", "-3", check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"{ERROR}`max_steps` must be a non-negative integer or -1 (infinite steps). You passed in -3."]


# ----------------------------------------------------------------------------------------------------------------
# Tracebacks that became one line


def test_a_read_only_sparse_depth_cache_keeps_the_sfm_result(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    os.chmod(cache, 0o555)
    args = [a if a != str(tmp_path / "cache") else str(cache / "sub") for a in run_args(tmp_path)]
    proc = run_unprivileged("fit", *args, "--trainer.max_steps", "1")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "sparse depth: cannot write the cache " in proc.stderr and "using the SfM result in memory" in proc.stderr
    assert "Traceback" not in proc.stderr and last_step(tmp_path / "run" / "checkpoints" / "last.ckpt") == 1


def test_earlier_results_that_cannot_be_moved_aside_stop_test_before_the_render(resumed, tmp_path):
    """The run folder is sticky and neither it nor test/ is the user's: test/ cannot be renamed (as in a shared
    folder). Checked before anything is rendered."""
    if os.geteuid() != 0:
        pytest.skip("needs root to give the folders to another user")
    run_dir = tmp_path / "run"
    shutil.copytree(resumed / "run" / "checkpoints", run_dir / "checkpoints")
    (run_dir / "test").mkdir()
    (run_dir / "test" / "summary.json").write_text("earlier results")
    for path in (run_dir, run_dir / "test"):
        os.chown(path, 65534, 65534)
    os.chmod(run_dir, 0o1777)
    args = [a if not a.startswith(str(tmp_path / "cache")) else str(resumed / "cache") for a in run_args(tmp_path)]
    args = [a if a != str(tmp_path / "data") else str(resumed / "data") for a in args]
    proc = run_unprivileged("test", *args, "--ckpt_path", "last", "--evaluation.lpips", "false")
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines() == [
        f"{ERROR}the earlier results in {run_dir / 'test'} cannot be moved aside for the new ones (Operation not "
        "permitted); move them yourself, or choose another --evaluation.output_dir"]
    assert not (run_dir / "test.partial").exists()


# ----------------------------------------------------------------------------------------------------------------
# process-data


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    from simplenerf.synthetic.generate import make_synthetic_scene

    root = make_synthetic_scene(tmp_path_factory.mktemp("photos") / "scene", height=240, width=320, n_frames=6)
    return root / "images"


def test_process_data_never_writes_into_its_input(photos, tmp_path):
    before = sorted(p.name for p in photos.iterdir())
    for output, where in ((photos, "is"), (photos / "out", "is inside"), (photos.parent, "contains")):
        proc = run("process-data", "--images", str(photos), "--output", str(output), "--overwrite", check=False)
        assert proc.returncode == 2
        assert proc.stderr.strip().splitlines() == [
            f"{ERROR}--output {output} {where} the photo folder {photos}: process-data never writes into its input; "
            "choose an --output outside it"]
    assert sorted(p.name for p in photos.iterdir()) == before
    # | --overwrite on a folder process-data did not write | refused, nothing deleted |
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    proc = run("process-data", "--images", str(photos), "--output", str(mine), "--overwrite", check=False)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"{ERROR}{mine} was not written by process-data (it has no {MARKER}), so --overwrite does not replace it; "
        "choose another --output, or empty it yourself"]
    assert (mine / "thesis.tex").read_text() == "precious"
    # | process-data into a read-only folder | one line, before any work |
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    os.chmod(read_only, 0o555)
    proc = run_unprivileged("process-data", "--images", str(photos), "--output", str(read_only / "scene"))
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"{ERROR}cannot write the output {read_only / 'scene'}: {read_only}: Permission denied"]


def test_process_data_overwrite_replaces_only_its_own_files_and_ctrl_c_writes_nothing(photos, tmp_path):
    out = tmp_path / "scene"
    # | Ctrl-C during structure from motion | exit status 130, one line, no output and no partial folder |
    proc = start(tmp_path, "process-data", "--images", str(photos), "--output", str(out), "--factors", "2")
    wait_for(proc, "photos: 6 from")
    proc.send_signal(signal.SIGINT)
    status, stderr = finish(proc)
    assert status == 130 and "Traceback" not in stderr, stderr[-2000:]
    assert stderr.strip().splitlines()[-1] == f"{ERROR}stopped by SIGINT before it finished"
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("stderr-")) == []

    run("process-data", "--images", str(photos), "--output", str(out), "--factors", "2")
    marker = json.loads((out / MARKER).read_text())
    assert set(marker["entries"]) == {"images", "images_2", "poses_bounds.npy", "sfm_report.json", "sfm_top_view.png",
                                      MARKER}
    assert json.loads((out / "sfm_report.json").read_text())["problems"] == []  # the synthetic cameras are sane
    assert "images/000.png" in marker["files"] and "images_2/000.png" in marker["files"]
    # | folders | with the user's umask (readable by others under umask 022), not mkdtemp's 0700 |
    mask = os.umask(0)
    os.umask(mask)
    for folder in (out, out / "images", out / "images_2"):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o777 & ~mask, folder
    # | --overwrite onto its own output | exactly the files it wrote are replaced; the user's files stay |
    (out / "notes.txt").write_text("mine")
    (out / "images" / "mine.txt").write_text("mine too")
    run("process-data", "--images", str(photos), "--output", str(out), "--factors", "4", "--overwrite")
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [MARKER, "images", "images_4", "notes.txt", "poses_bounds.npy", "sfm_report.json", "sfm_top_view.png"])
    assert (out / "notes.txt").read_text() == "mine" and (out / "images" / "mine.txt").read_text() == "mine too"
    assert sorted(p.name for p in (out / "images").iterdir()) == [*(f"{i:03d}.png" for i in range(6)), "mine.txt"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_process_data_names_identical_photos_before_sfm(photos, tmp_path):
    copy = Path(shutil.copytree(photos, tmp_path / "photos"))
    shutil.copyfile(copy / "000.png", copy / "006.png")
    proc = run("process-data", "--images", str(copy), "--output", str(tmp_path / "scene"), check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        f"{ERROR}photos 000.png and 006.png in {copy} are identical or nearly (mean difference under 2/255): structure "
        "from motion needs photos from different positions; remove the copies")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_process_data_judges_an_implausible_camera():
    """What two scenes' photos gave (issue 23): a focal length 6x the EXIF one, radial distortion 13.7, two groups."""
    report = {"size": [240, 320], "exif_focal_px": 300.0, "attempt": "default",
              "attempts": [{"name": "default", "groups": [4, 2]}],
              "cameras": [{"param_names": "f, cx, cy, k", "params": [1800.0, 160.0, 120.0, 13.7]}]}
    assert judge(report) == [
        "the camera's focal length 1800 px is 6 x the EXIF focal length 300 px",
        "the camera's radial distortion 13.7 is extreme (over 0.5)",
        "the photos register in 2 disjoint groups (4, 2 photos): only the largest is the scene",
    ]
    report.update(exif_focal_px=None, attempts=[{"name": "default", "groups": [6]}])
    report["cameras"][0]["params"] = [2400.0, 160.0, 120.0, 0.01]
    assert judge(report) == [
        "the camera's focal length 2400 px is a 7.6 deg field of view, outside a plausible 10-140 deg"]
    report["cameras"][0]["params"] = [300.0, 160.0, 120.0, 0.01]
    assert judge(report) == []
