"""The quality sweeps (configs/sweeps/quality_grid.yaml, fern_cpu.yaml) plan the runs the bash drivers they replace
ran (benchmarks/quality_grid.sh, benchmarks/fern_cpu.sh until 2026-12-03), config for config; and what those sweeps
need of the sweep file: a scene without reference depth (`reference_depth: none`), the held-out SfM depth error
(`heldout_depth`) and full-frame scores in the table (`scores: full`), run for real on a tiny synthetic scene."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from simplenerf.commands import main
from simplenerf.experiments.plan import build_plan, digest_of, resolved_for_scene
from simplenerf.experiments.spec import SweepError, load_sweep
from simplenerf.experiments.state import read_state
from tests.conftest import REPO
from tests.experiments.sweep_fixtures import models, synthetic_scenes, tiny_configs, write_sweep

SWEEPS = REPO / "configs" / "sweeps"
LLFF = REPO.parent / "shared" / "data" / "nerf_llff_data"
CLIP = REPO.parent / "shared" / "data" / "realestate10k" / "000c3ab189999a83"


def quality_grid_args(variant: str, scene: Path, llff: bool, seed: int, steps: int, extra: list[str]) -> list[str]:
    """The fit arguments benchmarks/quality_grid.sh gave a run (with STEPS, default DEPTH_WEIGHT, no RESUME), as it
    computed them: the variant's config of the scene's format, the seed twice, the budget, the warm-up at 10% of it
    (not for DS-NeRF), then EXTRA. The configs of configs/grid/ that these sweeps use have no concentration losses."""
    prefix = "" if llff else "realestate_"
    warm, weight = steps // 10, 0.1
    args = ["--config", str(REPO / "configs" / "grid" / f"{prefix}{variant}.yaml"),
            "--data.init_args.scene_dir", str(scene), "--seed_everything", str(seed), "--data.init_args.seed",
            str(seed), "--trainer.max_steps", str(steps), "--model.lr_scheduler.init_args.decay_steps", str(steps),
            "--trainer.val_check_interval", str(steps), "--checkpoint.every_n_train_steps", str(steps)]
    if not variant.endswith("dsnerf"):
        schedule = f"[[0, 0.0], [{warm}, {weight}]]"
        args += ["--trainer.callbacks.init_args.schedules",
                 f"{{points: {schedule}, views: {schedule}, cfc: {schedule}}}"]
    return args + extra


def fern_cpu_args(variant: str, scene: Path) -> list[str]:
    """The fit arguments benchmarks/fern_cpu.sh gave a variant (no seed: the CLI's default, 0). Its
    `--model.supervision` had stopped parsing when the loss became `model.objective`: the option is that one now."""
    config = {"bidirectional": "fern_simplenerf", "one_way": "fern_simplenerf", "dsnerf": "fern_dsnerf"}[variant]
    supervision = [] if variant == "dsnerf" else ["--model.objective.supervision", variant]
    return ["--config", str(REPO / "configs" / "cpu" / f"{config}.yaml"), *supervision,
            "--data.init_args.scene_dir", str(scene)]


def planned(name: str, monkeypatch):
    monkeypatch.chdir(REPO)  # the sweep files' paths are relative to the repository root
    path = SWEEPS / f"{name}.yaml"
    return build_plan(load_sweep(path), path, check_scenes=False)


def test_quality_grid_sweep_plans_the_drivers_fits(monkeypatch):
    plan = planned("quality_grid", monkeypatch)
    assert [u.stage for u in plan.units if u.stage in ("dense", "depth", "masks")] == []  # no reference depth
    fits = {u.key: u for u in plan.stage("fit")}
    models = {"simplenerf": "SimpleNeRF", "dsnerf": "DS-NeRF"}
    scenes = {"fern": LLFF / "fern", "horns": LLFF / "horns", "000c3ab189999a83": CLIP}
    assert set(fits) == {f"{s}/2v/{m}/seed{seed}" for s in scenes for m in models.values() for seed in (0, 1, 2)}
    extra = ["--data.init_args.rays_per_batch", "256", "--data.init_args.sparse_rays_per_batch", "64",
             "--trainer.limit_val_batches", "0"]
    cache: dict = {}
    for variant, model in models.items():
        for scene, folder in scenes.items():
            for seed in (0, 1, 2):
                args = quality_grid_args(variant, folder.resolve(), folder != CLIP, seed, 1000, extra)
                driver = resolved_for_scene(args, str(folder.resolve()), "driver", cache)
                assert digest_of(driver) == fits[f"{scene}/2v/{model}/seed{seed}"].digest, (variant, scene, seed)
    tests = plan.stage("test")
    assert len(tests) == 18 and all(t.needs == [f"fit:{t.key}"] for t in tests)
    heldout = {t.key for t in tests if t.extra.get("heldout_depth")}
    assert heldout == {k for k in fits if not k.startswith("000c3ab189999a83/")}  # LLFF scenes only, as the driver
    assert all(t.extra["heldout_depth"] == f"{t.folder}/heldout_depth.json" for t in tests if t.key in heldout)
    assert plan.stage("table")[0].extra["scores"] == "full"


def test_fern_cpu_sweep_plans_the_drivers_fits(monkeypatch):
    plan = planned("fern_cpu", monkeypatch)
    fits = {u.key: u for u in plan.stage("fit")}
    assert set(fits) == {f"fern/2v/{v}/seed0" for v in ("bidirectional", "one_way", "dsnerf")}
    cache: dict = {}
    for variant in ("bidirectional", "one_way", "dsnerf"):
        scene = str((LLFF / "fern").resolve())
        driver = resolved_for_scene(fern_cpu_args(variant, Path(scene)), scene, "driver", cache)
        assert digest_of(driver) == fits[f"fern/2v/{variant}/seed0"].digest, variant
    assert [u.stage for u in plan.units if u.stage in ("dense", "depth", "masks")] == []
    assert all(t.extra.get("heldout_depth") for t in plan.stage("test"))


def test_a_sweep_without_reference_depth_scores_full_frames_and_heldout_depth(tmp_path, capsys):
    """`reference_depth: none`: no dense NeRF and no masks job; each test also writes heldout_depth.json, and the
    table shows full-frame scores and the held-out error."""
    configs = tiny_configs(tmp_path / "configs")
    (scene,) = synthetic_scenes(tmp_path / "data", n=1)
    shutil.rmtree(scene / "depths")  # a real scene's case: no depth maps of its own
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(scene), "reference_depth": "none"}], [2],
                       models(configs, ("SimpleNeRF",)), configs, tmp_path / "out", heldout_depth=True, scores="full",
                       tables={})
    main(["sweep", "--config", str(path)])
    out = tmp_path / "out"
    assert not (out / "dense").exists() and not (out / "masks").exists()  # no dense NeRF, no masks job
    errors = {}
    for model in ("SimpleNeRF",):
        run = out / "runs" / "scene0" / "2v" / model / "seed0"
        assert read_state(run, "test")["status"] == "done"
        summary = json.loads((run / "test" / "summary.json").read_text())
        assert summary["psnr"] is not None and summary["masked_psnr"] is None and summary["depth_mae"] is None
        heldout = json.loads((run / "heldout_depth.json").read_text())
        assert heldout["ckpt"] == str(run / "checkpoints" / "last.ckpt") and heldout["rel_error_mean"] > 0
        assert heldout["untrained"] == [] and {"points", "views"} <= set(heldout["depths"])  # warmed up, so trained
        errors[model] = (f"{summary['psnr']:.2f}", f"{heldout['rel_error_mean']:.4f}",
                         f"{heldout['rel_error_median']:.4f}")
    table = (out / "results.md").read_text()
    assert table.startswith("# Results\n\n## LLFF\n\nFull-frame scores.") and "Held-out err.:" in table
    assert "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | MAE ↓ | SROCC ↑ | held-out err. ↓ | held-out err. median ↓ |" in table
    for model, (psnr, mean, median) in errors.items():
        cells = next(line for line in table.splitlines() if line.startswith(f"| {model} |")).split(" | ")
        # no LPIPS in the tiny config, no depth maps to score MAE and SROCC against
        assert (cells[1], *cells[3:8]) == ("-", psnr, "-", "-", mean, f"{median} |")


def test_an_unknown_scores_word_is_refused(tmp_path):
    configs = tiny_configs(tmp_path / "configs")
    path = write_sweep(tmp_path / "sweep.yaml", [{"path": str(tmp_path)}], [2], models(configs), configs,
                       tmp_path / "out", scores="masked-only")
    with pytest.raises(SweepError, match=r"scores 'masked-only' is not one of masked, full, both"):
        load_sweep(path)


def test_realestate_grid_sweep_runs_the_reference_beside_its_variants(monkeypatch):
    """configs/sweeps/realestate_grid.yaml: the RealEstate-10K clip, seeds 0-2, at quality_grid's short budget; the
    Simple-RF config as it is, the same with the distortion loss from step 300 (and nothing else different), and its
    DS-NeRF baseline; full-frame scores, no held-out depth (no SfM reference for the clip's held-out frames)."""
    plan = planned("realestate_grid", monkeypatch)
    fits = {u.key: u for u in plan.stage("fit")}
    models = ("Simple-RF", "Simple-RF-distortion", "DS-NeRF")
    assert set(fits) == {f"000c3ab189999a83/2v/{m}/seed{seed}" for m in models for seed in (0, 1, 2)}
    for key, unit in fits.items():
        config = "realestate_dsnerf" if unit.labels["model"] == "DS-NeRF" else "realestate_simplerf"
        assert f"configs/grid/{config}.yaml" in " ".join(unit.args) and "1000" in unit.args, key
    plain, distortion = (fits[f"000c3ab189999a83/2v/{m}/seed0"] for m in models[:2])
    differ = [(a, b) for a, b in zip(plain.args, distortion.args, strict=True) if a != b and a != plain.folder]
    assert len(differ) == 1 and "fine_distortion: [[0, 0.0], [300, 0.03]]" in differ[0][1]
    assert "distortion" not in differ[0][0]
    assert len({u.digest for u in fits.values()}) == 9
    tests = plan.stage("test")
    assert len(tests) == 9 and not any(t.extra.get("heldout_depth") for t in tests)
    assert plan.stage("table")[0].extra["scores"] == "full"


def test_quality_images4_sweep_compares_the_images4_configs_on_every_seed(monkeypatch):
    """configs/sweeps/quality_images4.yaml: grid SimpleNeRF and its DS-NeRF twin at images_4, seeds 0-2, each fit on
    its own config, each test with the held-out depth; the table reads full-frame scores."""
    plan = planned("quality_images4", monkeypatch)
    assert [u.stage for u in plan.units if u.stage in ("dense", "depth", "masks")] == []
    fits = {u.key: u for u in plan.stage("fit")}
    configs = {"SimpleNeRF": "configs/grid/simplerf_images4.yaml", "DS-NeRF": "configs/grid/dsnerf_images4.yaml"}
    assert set(fits) == {f"fern/2v/{model}/seed{seed}" for model in configs for seed in (0, 1, 2)}
    for key, unit in fits.items():
        assert configs[unit.labels["model"]] in " ".join(unit.args), key
    assert len({u.digest for u in fits.values()}) == 6
    tests = plan.stage("test")
    assert len(tests) == 6 and all(t.extra.get("heldout_depth") for t in tests)
    assert plan.stage("table")[0].extra["scores"] == "full"
