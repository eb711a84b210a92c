"""Every shipped YAML under configs/ parses against the real CLI (keys, types, class paths), without running."""

from pathlib import Path

import pytest
import yaml

from simplenerf.run.cli import SimpleNeRFCLI, make_cli

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
OVERRIDES = sorted((CONFIG_DIR / "overrides").rglob("*.yaml"))  # partial: added after a complete config
SWEEPS = sorted((CONFIG_DIR / "sweeps").rglob("*.yaml"))  # sweep files (simplenerf.experiments.spec), not CLI configs
CONFIGS = sorted(p for p in CONFIG_DIR.rglob("*.yaml") if p not in OVERRIDES and p not in SWEEPS)  # complete configs


class ParseOnlyCLI(SimpleNeRFCLI):
    def instantiate_classes(self) -> None:  # parse and validate, but build nothing (data may be absent here)
        pass


def parse(config: Path, *extra: str):
    """The parsed config of `config` (+ extra CLI arguments, e.g. more --config files)."""
    # args given explicitly: pytest's own argv must not be parsed
    return make_cli(["--config", str(config), *extra], run=False, cli_class=ParseOnlyCLI).config


def test_there_are_configs():
    names = {c.name for c in CONFIGS}
    assert {"llff.yaml", "dsnerf.yaml", "demo.yaml"} <= names


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: str(p.relative_to(CONFIG_DIR)))
def test_config_parses(config):
    cfg = parse(config)
    assert cfg.data.class_path.startswith("simplenerf.")
    assert cfg.trainer.max_steps > 0


@pytest.mark.parametrize("override", OVERRIDES, ids=lambda p: str(p.relative_to(CONFIG_DIR)))
def test_override_parses_on_top_of_the_paper_config(override):
    cfg = parse(CONFIG_DIR / "llff.yaml", "--config", str(override))
    if override.parent.name == "views":
        assert cfg.data.init_args.n_views == int(override.stem)


def test_dsnerf_is_simplenerf_without_its_regularisers():
    llff, dsnerf = parse(CONFIG_DIR / "llff.yaml").as_dict(), parse(CONFIG_DIR / "dsnerf.yaml").as_dict()
    assert dsnerf["data"]["init_args"]["sparse_rays_per_batch"] == 2048
    assert dsnerf["model"]["objective"]["sparse_depth_weight"] == 0.1
    assert len(llff["model"]["augmentations"]) == 2 and llff["model"]["objective"]["coarse_fine_mask"] is not None
    llff["model"]["augmentations"] = dsnerf["model"]["augmentations"]
    llff["model"]["objective"]["coarse_fine_mask"] = dsnerf["model"]["objective"]["coarse_fine_mask"]
    for section in ("trainer", "checkpoint", "config"):  # run folders and the warm-up callback differ by design
        dsnerf[section], llff[section] = None, None
    assert dsnerf == llff


def test_paper_config_keeps_paper_settings():
    cfg = parse(Path(__file__).resolve().parents[1] / "configs" / "llff.yaml")
    nerf = cfg.model.nerf.init_args
    assert (nerf.num_coarse, nerf.num_fine) == (64, 128)
    for field in (nerf.coarse, nerf.fine):
        assert field.class_path == "simplenerf.model.fields.RadianceField"
        f = field.init_args
        assert (f.point_bands, f.view_bands, f.num_layers, f.width, f.skip_layer) == (10, 4, 8, 256, 5)
    assert cfg.model.optimizer.class_path == "torch.optim.Adam" and cfg.model.optimizer.init_args.lr == 5e-4
    assert cfg.model.lr_scheduler.init_args.decay_rate == 0.1 and cfg.model.lr_scheduler.init_args.decay_steps == 250000
    assert cfg.trainer.max_steps == 100000
    assert cfg.data.init_args.factor == 4 and cfg.data.init_args.rays_per_batch == 2048


@pytest.mark.parametrize("name", ["llff.yaml", "realestate.yaml"])
def test_paper_configs_warm_up_as_the_paper(name):
    """L_ap, L_av and L_cfc are 0 before iteration 10000, then 0.1 (paper Sec. 4.4; the release)."""
    cfg = parse(Path(__file__).resolve().parents[1] / "configs" / name)
    [schedule] = [c for c in cfg.trainer.callbacks if c.class_path.endswith("LossWeightSchedule")]
    expected = [[0, 0.0], [10000, 0.1]]
    assert {k: [list(p) for p in v] for k, v in schedule.init_args.schedules.items()} == {
        "points": expected, "views": expected, "cfc": expected}


def test_unknown_key_is_rejected(capsys):
    with pytest.raises(SystemExit) as exit_info:
        parse(CONFIGS[0], "--model.no_such_option", "1")
    assert exit_info.value.code != 0


def flatten(tree, prefix=""):
    """{"a.b.0.c": leaf, ...} of a nested dict/list config."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in flatten(sub, f"{prefix}{key}.").items()}
    if isinstance(tree, list):
        return {k: v for i, sub in enumerate(tree) for k, v in flatten(sub, f"{prefix}{i}.").items()}
    return {prefix.rstrip("."): tree}


ABLATIONS = {
    # file: (augmentation names, their stages, what may differ from the paper config)
    "no_points_aug": (["views"], None),
    "no_views_aug": (["points"], None),
    "no_coarse_fine": (["points", "views", "points_fine", "views_fine"], None),
    "no_reliable_depth": (["points", "views"], "TrustAll"),
    "identical_aug": (["points", "views"], None),
    "smaller_network": (["points", "views"], None),
}


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_ablation_changes_only_what_it_ablates(name):
    paper = parse(CONFIG_DIR / "llff.yaml").as_dict()
    ablated = parse(CONFIG_DIR / "llff.yaml", "--config", str(CONFIG_DIR / "overrides/ablations" / f"{name}.yaml"))
    ablated = ablated.as_dict()
    names, mask = ABLATIONS[name]
    assert [a["init_args"]["name"] for a in ablated["model"]["augmentations"]] == names
    paper_flat, ablated_flat = flatten(paper), flatten(ablated)
    changed = {k for k in paper_flat.keys() | ablated_flat.keys() if paper_flat.get(k) != ablated_flat.get(k)}
    changed -= {"config.0", "config.1"}
    allowed = ("model.augmentations.", "model.objective.coarse_fine_mask", "trainer.callbacks.")
    assert changed and all(k.startswith(allowed) for k in changed), sorted(changed)
    augs = ablated["model"]["augmentations"]
    fields = [a["init_args"]["field"] and a["init_args"]["field"]["init_args"] for a in augs]  # None: a preset's
    if name == "identical_aug":
        assert all(f == fields[0] for f in fields)
        assert fields[0]["density_bands"] is None and fields[0]["view_dependent"]
    if name == "smaller_network":
        assert fields[0]["num_layers"] == 4 and fields[0]["density_bands"] is None
    if name == "no_coarse_fine":
        assert ablated["model"]["objective"]["coarse_fine_mask"] is None
        assert [a["init_args"]["stage"] for a in augs] == ["coarse", "coarse", "fine", "fine"]
    if mask:
        assert all(a["init_args"]["mask"]["class_path"].endswith(mask) for a in augs)
        assert ablated["model"]["objective"]["coarse_fine_mask"]["class_path"].endswith(mask)


@pytest.mark.parametrize("sweep", SWEEPS, ids=lambda p: str(p.relative_to(CONFIG_DIR)))
def test_sweep_file_parses_and_its_model_configs_parse(sweep, monkeypatch):
    """Each sweep file against the sweep schema, and every (model, scene) config it names against the real CLI (its
    scenes need not exist here: the plan's dry-run mode)."""
    from simplenerf.experiments.plan import build_plan
    from simplenerf.experiments.spec import load_sweep

    monkeypatch.chdir(CONFIG_DIR.parent)  # the sweep files' paths are relative to the repository root
    plan = build_plan(load_sweep(sweep), sweep, check_scenes=False)
    assert plan.stage("fit") and plan.stage("test") and plan.stage("table")


def test_the_realestate_simple_rf_config_has_the_llff_ones_augmentations_and_schedules():
    # The files as written: the augmentation list and the schedules are copies that must not drift.
    llff, realestate = (yaml.safe_load((CONFIG_DIR / "grid" / f"{name}.yaml").read_text())
                        for name in ("simplerf", "realestate_simplerf"))
    assert realestate["model"]["augmentations"] == llff["model"]["augmentations"]
    assert realestate["trainer"]["callbacks"] == llff["trainer"]["callbacks"]
