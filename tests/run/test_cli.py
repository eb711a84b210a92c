"""The real command line, end to end: fit, resume, test, print_config, and one-line errors on bad input."""

from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
import yaml

from simplenerf.commands import LIGHTNING_VERBS, TASKS, VERBS, main
from simplenerf.run.cli import load_for_tool
from tests import preloaded_cli
from tests.conftest import REPO, shared_dir

SMALL = [
    "--model.chunk", "4096", "--data.init_args.rays_per_batch", "64", "--data.init_args.sparse_rays_per_batch", "32",
    "--trainer.val_check_interval", "2", "--checkpoint.every_n_train_steps", "2",
]
SIZES = {"num_layers": 2, "width": 16, "skip_layer": 1, "num_coarse": 8, "num_fine": 8}


def shrink(node, sizes: dict[str, int] = SIZES):
    """A config tree with every network size named in `sizes` replaced by that size."""
    if isinstance(node, dict):
        return {key: sizes[key] if key in sizes else shrink(value, sizes) for key, value in node.items()}
    if isinstance(node, list):
        return [shrink(value, sizes) for value in node]
    return node


def tiny_model(tmp: Path) -> Path:
    """An override with the demo's NeRF and augmentations at a tiny size (lists are replaced whole, so all of it)."""
    model = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())["model"]
    tmp.mkdir(parents=True, exist_ok=True)
    path = tmp / "tiny_model.yaml"
    path.write_text(yaml.safe_dump({"model": {key: shrink(model[key]) for key in ("nerf", "augmentations")}}))
    return path


def run(*args: str, env: dict | None = None, check: bool = True) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true", **(env or {})}
    proc = preloaded_cli.run(list(args), cwd=REPO, env=full_env, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"exit {proc.returncode}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}")
    return proc


def run_args(tmp: Path, shared: Path | None = None) -> list[str]:
    """The demo config (SimpleNeRF on the synthetic scene, 96x128) shrunk to seconds, with its run folder in `tmp` and
    its generated scene and SfM cache in `shared` (default `tmp`)."""
    shared = shared or tmp
    return [
        "--config", "configs/demo.yaml", "--config", str(tiny_model(tmp)), *SMALL,
        "--data.init_args.root", str(shared / "data"), "--data.init_args.sparse_depth_cache", str(shared / "cache"),
        "--trainer.default_root_dir", str(tmp / "run"),  # the W&B logger writes into the run folder too
    ]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A 4-step fit, resumed to 6 steps with --ckpt_path last and a 3-frame video at the end; what each printed is
    kept in fit{1,2}.{stdout,stderr}."""
    tmp = tmp_path_factory.mktemp("cli")
    first = run("fit", *run_args(tmp), "--trainer.max_steps", "4")
    second = run("fit", *run_args(tmp), "--trainer.max_steps", "6", "--ckpt_path", "last", "--video.frames", "3",
                 "--video.scale", "0.25")
    for name, proc in (("fit1", first), ("fit2", second)):
        (tmp / f"{name}.stdout").write_text(proc.stdout)
        (tmp / f"{name}.stderr").write_text(proc.stderr)
    return tmp


def test_fit_writes_checkpoints_and_resumes(trained):
    ckpts = trained / "run" / "checkpoints"
    assert {"step000002.ckpt", "step000004.ckpt", "step000006.ckpt", "last.ckpt"} <= {p.name for p in ckpts.iterdir()}
    last = torch.load(ckpts / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 6  # resumed from step 4, not restarted
    assert (trained / "run" / "wandb").is_dir()  # the default logger ran, offline
    # SimpleNeRF's pieces were trained, and validation saved the reliability masks of the first train view.
    assert "augmentations.0.field.trunk.0.weight" in last["state_dict"]
    assert {"mask_points_step000002.png", "mask_views_step000002.png", "mask_cfc_step000002.png"} <= {
        p.name for p in (trained / "run" / "val").iterdir()
    }
    # ...and the validation renders of the validation view (simplenerf.run.callbacks.ValidationRenders, a CLI default).
    assert {f"step000004_{kind}.png" for kind in ("rgb", "depth", "accumulation", "error")} <= {
        p.name for p in (trained / "run" / "val").iterdir()
    }


def test_progress_lines_in_a_log_file(trained):
    """Without a terminal: a plain line per step here (max_steps / 100 rounds down to 1), one per checkpoint and
    validation; the resumed run counts from the checkpoint's step."""
    run_dir = trained / "run"
    first = (trained / "fit1.stdout").read_text().splitlines()
    number = r"\d+(\.\d+)?(e[+-]\d+)?"
    step1 = next(line for line in first if line.startswith("step 1/4"))
    assert re.fullmatch(rf"step 1/4 \(25%\)  loss {number}  psnr {number}  elapsed 0:00:\d\d  eta 0:\d\d:\d\d", step1)
    step2 = next(line for line in first if line.startswith("step 2/4 (50%)"))
    assert re.fullmatch(rf"step 2/4 \(50%\)  loss {number}  psnr {number}  \d+ rays/s  elapsed \S+  eta \S+", step2)
    after = first[first.index(step2) + 1 : first.index(step2) + 3]
    assert after[0] == f"step 2/4  checkpoint  {run_dir / 'checkpoints'}"
    assert re.fullmatch(rf"step 2/4  validation  psnr {number}", after[1])
    second = (trained / "fit2.stdout").read_text().splitlines()
    steps = [line.split()[1] for line in second if line.startswith("step ")]
    assert steps[0] == "4/6" and f"step 4/6  resumed from {run_dir / 'checkpoints' / 'last.ckpt'}" in second
    assert steps[1:] == ["5/6", "6/6", "6/6", "6/6"]


def test_a_normal_run_prints_no_library_noise(trained):
    for name in ("fit1", "fit2"):
        text = (trained / f"{name}.stdout").read_text() + (trained / f"{name}.stderr").read_text()
        for noise in ("Tip:", "deprecated", "Deprecat", "FutureWarning", "anonymous", "wandb leet", "wandb:",
                      "is not empty", "No seed found", "Traceback"):
            assert noise not in text, (name, noise)
        assert f"W&B: offline run in {trained / 'run' / 'wandb'}" in text


def test_help_describes_simplenerf_and_lists_every_verb_once_grouped_by_task():
    out = run("--help").stdout
    assert out.startswith("usage: simplenerf <command> [options]")
    assert "SimpleNeRF (SIGGRAPH Asia 2023): Neural Radiance Fields from 2 to 4 photos" in out
    groups = out.split("\n\n")[2:]
    assert [group.splitlines()[0] for group in groups] == [f"{task}:" for task in TASKS]
    for task, group in zip(TASKS, groups, strict=True):
        listed = group.splitlines()[1:]
        assert [line.split()[0] for line in listed] == [name for name, v in VERBS.items() if v.task == task]
        assert all(line.startswith("  ") and len(line.split(maxsplit=1)) == 2 for line in listed)  # verb and line
    assert sorted(line.split()[0] for g in groups for line in g.splitlines()[1:]) == sorted(VERBS)  # each once
    assert run().stdout == out  # no verb: the same overview


def test_version():
    from simplenerf import __version__

    assert run("--version").stdout == f"simplenerf {__version__}\n"


@pytest.mark.parametrize("verb", [v for v in VERBS if v not in LIGHTNING_VERBS])
def test_help_prints_the_verbs_examples_as_written(verb, capsys):
    """A verb's --help shows its module's docstring as it is in the source: an example continued with a backslash
    prints with the backslash and the line break, so it can be pasted into a shell."""
    import ast
    import importlib

    module = importlib.import_module(VERBS[verb].target.partition(":")[0])
    source = Path(module.__file__).read_text()
    docstring = ast.get_source_segment(source, ast.parse(source).body[0].value)
    written = docstring[docstring.index('"""') + 3 : -3]
    with contextlib.suppress(SystemExit):  # (some verbs print their help and return)
        main([verb, "--help"])
    assert written.strip() in capsys.readouterr().out


@pytest.mark.parametrize("verb", list(VERBS))
def test_every_verb_answers_help(verb, capsys):
    with pytest.raises(SystemExit) as done:
        main([verb, "--help"])
        raise SystemExit(0)  # a verb that prints its help and returns
    out = capsys.readouterr().out
    assert done.value.code in (0, None) and out.startswith("usage: simplenerf")
    assert verb in out.splitlines()[0]
    if verb not in LIGHTNING_VERBS:  # the module's docstring: a description and an example of the verb
        assert f"simplenerf {verb} " in out.split("\n\n", 1)[1]


def test_an_unknown_verb_is_one_error_line():
    proc = run("fitt", "--config", "configs/demo.yaml", check=False)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == ("simplenerf: error: unknown command 'fitt'; did you mean fit? (`simplenerf --help` lists "
                           "the commands)\n")


def test_a_verbs_bad_option_is_one_error_line_and_a_hint():
    proc = run("render-video", "--config", "configs/demo.yaml", check=False)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == ["simplenerf: error: the following arguments are required: --ckpt_path",
                                        "hint: `simplenerf render-video --help` lists every option"]


def test_tools_are_one_call_of_their_verb():
    """tools/<verb>.py (the layout's thin scripts): each runs `simplenerf <verb>` with its arguments, nothing else."""
    scripts = sorted((REPO / "tools").glob("*.py"))
    assert scripts
    for script in scripts:
        verb = script.stem.replace("_", "-")
        assert verb in VERBS, script
        code = [line for line in script.read_text().splitlines()[1:] if line.strip()]
        assert code == ["import sys", "from simplenerf.commands import main", 'if __name__ == "__main__":',
                        f'    main(["{verb}", *sys.argv[1:]])'], script


def test_final_video_is_h264_and_logged_to_wandb(trained):
    from tests.viz.test_video import mp4_codec

    video = trained / "run" / "video_spiral.mp4"
    assert mp4_codec(video) == "avc1"
    logged = list((trained / "run" / "wandb").glob("offline-run-*/files/media/videos/video/spiral_*.mp4"))
    assert len(logged) == 1 and logged[0].read_bytes() == video.read_bytes()
    assert f"video: {video} (3 frames of 64x24, spiral)" in (trained / "fit2.stdout").read_text()


def test_validate_reports_psnr(trained):
    out = run("validate", *run_args(trained), "--ckpt_path", "last").stdout
    assert "val/psnr" in out


def test_test_writes_metrics_and_renders(trained):
    lpips_file = shared_dir() / "data/lpips/alexnet_trunk_and_lpips_lin_v0.1.npz"
    extra = [] if lpips_file.exists() else ["--evaluation.lpips", "false"]
    run("test", *run_args(trained), "--ckpt_path", "last", *extra, env={"SIMPLENERF_LPIPS_WEIGHTS": str(lpips_file)})
    out = trained / "run" / "test"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3  # frames 0, 8, 16 of 20
    for key in ("psnr", "ssim", "depth_mae", "depth_srocc"):
        assert isinstance(summary[key], float)
    assert 0 < summary["psnr"] < 100 and -1 <= summary["ssim"] <= 1 and summary["depth_mae"] >= 0
    if lpips_file.exists():
        # LPIPS is a weighted feature distance: >= 0 but not bounded by 1 (a barely trained model gave 1.013)
        assert 0 <= summary["lpips"] < 10
    rows = (out / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("frame,index,psnr,ssim,lpips,depth_mae,depth_srocc") and len(rows) == 4
    assert {p.name for p in (out / "rgb").iterdir()} == {"000.png", "008.png", "016.png"}
    assert (out / "depth" / "008.npy").is_file() and (out / "depth" / "008.png").is_file()
    run_info = json.loads((out / "run.json").read_text())
    assert run_info["checkpoint"].endswith("last.ckpt")
    assert not (trained / "run" / "test.partial").exists()


def test_test_keeps_earlier_results_and_the_run_config(trained):
    run_dir = trained / "run"
    (run_dir / "test").mkdir(exist_ok=True)
    (run_dir / "test" / "marker").write_text("earlier results")
    config = (run_dir / "config.yaml").read_bytes()
    archives = set(run_dir.glob("test.2*"))
    proc = run("test", *run_args(trained), "--ckpt_path", "last", "--evaluation.lpips", "false")
    [archive] = set(run_dir.glob("test.2*")) - archives
    assert (archive / "marker").read_text() == "earlier results"
    assert f"earlier results of {run_dir / 'test'} moved to {archive}" in proc.stdout
    assert (run_dir / "test" / "summary.json").is_file() and not (run_dir / "test" / "marker").exists()
    # The run's config.yaml still says how it was trained; the test's own config is beside its results.
    assert (run_dir / "config.yaml").read_bytes() == config
    test_config = yaml.safe_load((run_dir / "test" / "config.yaml").read_text())
    assert test_config["evaluation"]["lpips"] is False
    assert test_config["ckpt_path"] == "last"  # as given; summary.json names the file it resolved to
    summary = json.loads((run_dir / "test" / "summary.json").read_text())
    assert summary["config"] == str(run_dir / "test" / "config.yaml")
    assert summary["checkpoint"] == str(run_dir / "checkpoints" / "last.ckpt")


def test_a_runs_saved_config_is_a_config_for_test_and_the_tools(trained, tmp_path):
    """<run>/config.yaml holds the fit's own arguments too (overwrite, ckpt_path: last, weights_only); test and
    load_for_tool (what the verbs that read a run start from) take the file as it is."""
    run_dir = trained / "run"
    saved = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert {"overwrite", "ckpt_path", "weights_only"} <= saved.keys() and saved["ckpt_path"] == "last"
    out = tmp_path / "elsewhere"
    proc = run("test", "--config", str(run_dir / "config.yaml"), "--ckpt_path",
               str(run_dir / "checkpoints" / "last.ckpt"), "--evaluation.lpips", "false",
               "--trainer.default_root_dir", str(out), "--trainer.logger.init_args.save_dir", str(out))
    assert "args parameter" not in proc.stderr  # Lightning's warning about given args is not the user's business
    assert json.loads((out / "test" / "summary.json").read_text())["frames"] == 3
    cli = load_for_tool([str(run_dir / "config.yaml")], [], ckpt=str(run_dir / "checkpoints" / "last.ckpt"))
    weights = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)["state_dict"]
    assert not cli.model.training and all(torch.equal(v, weights[k]) for k, v in cli.model.state_dict().items())
    assert cli.trainer.default_root_dir == str(run_dir)
    # The file itself is unchanged; only what is parsed drops the fit's arguments.
    assert yaml.safe_load((run_dir / "config.yaml").read_text()) == saved


def test_run_history_reads_what_the_fit_and_its_resume_logged(trained, tmp_path):
    """`simplenerf run-history` reads the W&B files of both runs of the resumed fit (validations after steps 2, 4, 6,
    logged at global steps 1, 3, 5), with no network. The two W&B runs the fits printed are copied to a folder of
    their own (other tests validate the same run folder, which adds W&B runs)."""
    for name in ("fit1", "fit2"):
        [folder] = re.findall(r"W&B: offline run in (\S+)", (trained / f"{name}.stdout").read_text())
        shutil.copytree(folder, tmp_path / "wandb" / Path(folder).name)
    proc = run("run-history", str(tmp_path), "--keys", "val/psnr")
    header, *rows = [line.split(",") for line in proc.stdout.splitlines()]
    assert header == ["step", "val/psnr"] and [int(r[0]) for r in rows] == [1, 3, 5]
    assert all(0 < float(r[1]) < 100 for r in rows)


def test_history_table_merges_a_steps_scalars():
    from simplenerf.commands.run_history import history_table

    rows = [{"trainer/global_step": 9, "train/loss": 0.5, "epoch": 0}, {"trainer/global_step": 9, "train/psnr": 20.0},
            {"trainer/global_step": 19, "train/loss": 0.25, "train/flag": True, "train/image": {"_type": "png"}},
            {"train/loss": 1.0}]  # a row without a step is left out
    assert history_table(rows, "train/.*") == (["step", "train/loss", "train/psnr"], [[9, 0.5, 20.0], [19, 0.25, ""]])


def test_missing_lpips_weights_stop_test_before_writing(trained, tmp_path):
    (trained / "run" / "test").mkdir(exist_ok=True)
    marker = trained / "run" / "test" / "marker"
    marker.write_text("earlier results")
    env = {"SIMPLENERF_LPIPS_WEIGHTS": str(tmp_path / "missing.npz"), "TORCH_HOME": str(tmp_path / "hub")}
    proc = run("test", *run_args(trained), "--ckpt_path", "last", env=env, check=False)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith("simplenerf: error:") and "SIMPLENERF_LPIPS_WEIGHTS" in line
    # The advice is one that works: `--evaluation.lpips false` (lpips_weights takes a path, not "none").
    assert "`--evaluation.lpips false`" in line and "lpips_weights none" not in line
    assert marker.read_text() == "earlier results"
    proc = run("test", *run_args(trained), "--ckpt_path", "last", "--evaluation.lpips", "false", env=env)
    assert json.loads((trained / "run" / "test" / "summary.json").read_text())["lpips"] is None


def test_bad_scene_is_one_line_error(tmp_path):
    proc = run(
        "fit", "--config", "configs/llff.yaml", "--data.init_args.scene_dir", str(tmp_path / "nope"),
        "--trainer.default_root_dir", str(tmp_path / "run"), check=False,
    )
    assert proc.returncode == 2
    expected = f"simplenerf: error: scene directory {tmp_path / 'nope'} does not exist"
    assert proc.stderr.strip().splitlines() == [expected]
    assert not (tmp_path / "run").exists()  # not even an empty run folder


def test_too_many_views_is_one_line_error(tmp_path):
    proc = run("fit", *run_args(tmp_path), "--data.init_args.n_views", "30", check=False)
    assert proc.returncode == 2
    assert "n_views=30 is not possible: the train pool has 17 frames" in proc.stderr


def test_print_config_is_commented_and_reloadable(tmp_path):
    printed = run("fit", "--config", "configs/demo.yaml", "--print_config=comments").stdout
    assert "# lambda_1, weight of the colour loss (main coarse, main fine and each augmentation)." in printed  # docs
    config = tmp_path / "printed.yaml"
    config.write_text(printed)
    assert yaml.safe_load(printed)["model"]["nerf"]["init_args"]["coarse"]["init_args"]["width"] == 64
    reprinted = run("fit", "--config", str(config), "--print_config").stdout
    original = run("fit", "--config", "configs/demo.yaml", "--print_config").stdout
    assert yaml.safe_load(reprinted) == yaml.safe_load(original)


def test_help_shows_argument_docs():
    out = run("fit", "--help").stdout
    assert "lambda_1, weight of the colour loss" in out


def test_user_augmentation_plugs_in_by_class_path(tmp_path):
    override = tmp_path / "user_aug.yaml"
    override.write_text(
        "model:\n"
        "  augmentations:\n"
        "    - class_path: tests.custom_augmentation.LowPassPointsAugmentation\n"
        "      init_args: {bands: 2, width: 16, num_layers: 2}\n"
        "  objective:\n"
        "    coarse_fine_mask: {class_path: simplenerf.method.reliability.PatchReprojectionMask}\n"
        "trainer:\n"
        "  callbacks:\n"
        "    - class_path: simplenerf.run.callbacks.LossWeightSchedule\n"
        "      init_args: {schedules: {lowpass: [[0, 0.0], [1, 0.1]]}}\n"
    )
    run("fit", *run_args(tmp_path), "--config", str(override), "--trainer.max_steps", "2")
    state = torch.load(tmp_path / "run/checkpoints/last.ckpt", map_location="cpu", weights_only=False)["state_dict"]
    assert state["augmentations.0.field.trunk.0.weight"].shape == (16, 15)  # gamma(p, 0, 2): 15 inputs


def test_user_loss_term_plugs_in_by_class_path(tmp_path):
    """A term defined outside the package (tests/custom_term.py) joins the objective from YAML: it is computed and
    logged by its name, and the warm-up schedule sets its weight by that name like a built-in term's."""
    override = tmp_path / "user_term.yaml"
    override.write_text(
        "model:\n"
        "  objective:\n"
        "    terms:\n"
        "      - class_path: tests.custom_term.OpacityTerm\n"
        "        init_args: {weight: 0.5, render: coarse}\n"
        "trainer:\n"
        "  log_every_n_steps: 1\n"
        "  logger:\n"
        "    class_path: lightning.pytorch.loggers.CSVLogger\n"
        f"    init_args: {{save_dir: {tmp_path / 'csv'}, name: run, version: 0}}\n"
        "  callbacks:\n"
        "    - class_path: simplenerf.run.callbacks.LossWeightSchedule\n"
        "      init_args: {schedules: {opacity: [[0, 0.0], [1, 0.25]]}}\n"
    )
    run("fit", *run_args(tmp_path), "--config", str(override), "--trainer.max_steps", "2")
    with open(tmp_path / "csv/run/version_0/metrics.csv") as f:
        rows = [row for row in csv.DictReader(f) if row["train_params/opacity"]]
    assert [(int(r["step"]), float(r["train_params/opacity"])) for r in rows] == [(0, 0.0), (1, 0.25)]
    assert rows[0]["train/loss_opacity"] == ""  # weight 0: not computed
    assert 0.0 <= float(rows[1]["train/loss_opacity"]) <= 1.0  # mean (1 - accumulation)^2 of the coarse render


def test_unreadable_image_stops_before_anything_is_written(synthetic_scene, tmp_path):
    import shutil

    scene = shutil.copytree(synthetic_scene, tmp_path / "scene")
    (scene / "images" / "005.png").write_bytes(b"truncated")
    proc = run(
        "fit", "--config", "configs/dsnerf.yaml", "--data.init_args.scene_dir", str(scene),
        "--data.init_args.factor", "1", "--trainer.default_root_dir", str(tmp_path / "run"), check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        f"simplenerf: error: cannot read image {scene / 'images' / '005.png'} (missing, truncated or not an image)"
    )
    assert not (tmp_path / "run" / "wandb").exists() and not (tmp_path / "run" / "checkpoints").exists()


def test_fit_without_a_logger(tmp_path):
    run("fit", *run_args(tmp_path), "--trainer.logger", "false", "--trainer.max_steps", "1")
    assert (tmp_path / "run/checkpoints/last.ckpt").is_file() and not (tmp_path / "run/wandb").exists()


def test_explicit_train_frames_without_test_frames_render_instead_of_scoring(tmp_path):
    """Own photos: `train_frames` + `test_every 0` trains on exactly those frames; `test` then has nothing to score and
    writes the train views' depth maps, point cloud and the spiral video instead, and says so. Nothing is scored, so
    neither command asks for LPIPS weights (a machine without them or a network runs both as they are)."""
    frames = ["--data.init_args.train_frames", "[1, 5, 9]", "--data.init_args.test_every", "0"]
    no_weights = {"SIMPLENERF_LPIPS_WEIGHTS": str(tmp_path / "missing.npz"), "TORCH_HOME": str(tmp_path / "hub")}
    fit = run("fit", *run_args(tmp_path), *frames, "--trainer.max_steps", "2", env=no_weights)
    assert "sparse depth: SfM on train views [1, 5, 9]" in fit.stdout
    test = run("test", *run_args(tmp_path), *frames, "--ckpt_path", "last", env=no_weights)
    assert "this split has no test frames (train frames [1, 5, 9]), so there are no metrics" in test.stdout
    out = tmp_path / "run" / "test"
    depth_files = sorted(p.name for p in (out / "depth").glob("*.npy"))
    assert len(depth_files) == 3 and (out / "points.ply").is_file() and (out / "video_spiral.mp4").stat().st_size > 0
    assert not (out / "metrics.csv").exists()


def test_depth_smoothness_fits_with_unseen_patches_and_is_refused_without(tmp_path):
    """RegNeRF's prior end to end: the data module serves the patches, the terms are logged; a weight without
    patches stops before the fit with one line naming the option to set."""
    smoothness = ["--model.objective.depth_smoothness_weight", "0.5"]
    refused = run("fit", *run_args(tmp_path), *smoothness, "--trainer.max_steps", "1", check=False)
    assert refused.returncode != 0 and not (tmp_path / "run/checkpoints").exists()
    assert "coarse_depth_smoothness, fine_depth_smoothness read patches from unseen cameras" in refused.stderr
    assert "unseen_patches_per_batch" in refused.stderr and "Traceback" not in refused.stderr
    run("fit", *run_args(tmp_path), *smoothness, "--data.init_args.unseen_patches_per_batch", "2",
        "--data.init_args.unseen_patch_size", "4", "--trainer.max_steps", "2", "--trainer.log_every_n_steps", "1")
    history = run("run-history", str(tmp_path / "run"), "--keys", "train/loss_(coarse|fine)_depth_smoothness")
    rows = list(csv.DictReader(history.stdout.splitlines()))
    assert len(rows) == 2
    assert all(float(row[f"train/loss_{stage}_depth_smoothness"]) > 0 for row in rows for stage in ("coarse", "fine"))
