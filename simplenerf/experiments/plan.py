"""A sweep as jobs: the stages of the paper's evaluation (Sec. 5.1, supplement Evaluation Details) with their
dependencies.

    dense (per scene; RealEstate-10K: per scene and view count)  dense reference NeRF, configs/dense/
      -> depth (same)            its depth of every frame (simplenerf.evaluation.reference_depth)
      -> masks (scene, views)    visibility masks of the test frames (simplenerf.evaluation.visibility)
    fit (scene, views, model, seed)
      -> test (same; needs the masks' reference depth)   test/summary.json, test/metrics.csv
      -> table                   results.md / results.csv, in the layout of Tables 1-3, beside the paper's rows

A scene with `reference_depth` (a folder, or `scene` for its own depth) has no dense and depth jobs; one with
`reference_depth: none` has no masks job either (its tests score full frames). With `heldout_depth`, the test of an LLFF
scene also writes `<run>/heldout_depth.json` (the depth error at held-out SfM points).

Each job is a `Unit`: its stage, key, folder, the CLI arguments it runs with and a `digest`, the hash of what it
computes (the resolved config with paths and logging left out, plus what it reads). A unit is done when its state
file (`<folder>/.sweep/<stage>.json`, `simplenerf.experiments.state`) says done with the same digest; a folder that
holds another digest's work stops the sweep (a run folder never mixes two configs).

Every model config is parsed against the real CLI here, once per (model, scene): a missing scene, a missing config
file, an unknown key or a config that does not parse stops the sweep before any job is submitted.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import logging
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

from simplenerf.experiments.spec import (
    NO_DEPTH,
    SCENE_DEPTH,
    SceneEntry,
    Sweep,
    SweepError,
    configs_for,
    scene_name,
    slug,
)
from simplenerf.experiments.state import read_state

# Left out of a digest: where things are written and how they are logged, not what is computed.
VOLATILE = ("config", "ckpt_path", "overwrite", "progress", "trainer.default_root_dir", "trainer.logger",
            "checkpoint.dirpath", "data.init_args.sparse_depth_cache", "trainer.enable_progress_bar")


@dataclass
class Unit:
    """One job of the sweep."""

    stage: str
    key: str
    """scene[/Nv][/model/seedS]: unique within the stage."""
    folder: str
    """The unit's folder (a run folder for dense / fit / test); its state is `<folder>/.sweep/<stage>.json`."""
    digest: str
    args: list[str] = field(default_factory=list)
    """CLI arguments (configs and overrides) without the logger's."""
    logger_args: list[str] = field(default_factory=list)
    needs: list[str] = field(default_factory=list)
    """Ids (`stage:key`) of the units whose outputs it reads."""
    labels: dict[str, str] = field(default_factory=dict)
    """scene, views, model, seed (status table and W&B tags)."""
    extra: dict = field(default_factory=dict)
    """Stage details: output folders, reference depth, max_steps, the table's runs."""

    @property
    def id(self) -> str:
        return f"{self.stage}:{self.key}"

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Unit:
        return cls(**data)


@dataclass
class Plan:
    sweep: Sweep
    output: Path
    units: list[Unit]
    warnings: list[str] = field(default_factory=list)

    def stage(self, stage: str) -> list[Unit]:
        return [u for u in self.units if u.stage == stage]

    def by_id(self) -> dict[str, Unit]:
        return {u.id: u for u in self.units}


def digest_of(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _drop(tree: dict, dotted: str) -> None:
    *path, last = dotted.split(".")
    node = tree
    for key in path:
        if not isinstance(node, dict) or key not in node:
            return
        node = node[key]
    if isinstance(node, dict):
        node.pop(last, None)


def resolved_config(args: list[str], entry: str) -> dict:
    """The config `args` resolve to (parsed by the real CLI, nothing built), without its paths and logging.
    SweepError naming `entry` with the CLI's error line if it does not parse."""
    from simplenerf.run.cli import SimpleNeRFCLI, make_cli
    from simplenerf.run.console import quiet_libraries

    class ParseOnly(SimpleNeRFCLI):
        def instantiate_classes(self) -> None:
            pass

    quiet_libraries()
    err = io.StringIO()
    seed_log = logging.getLogger("lightning.fabric.utilities.seed")  # "Seed set to 0" of every parse
    level = seed_log.level
    seed_log.setLevel(logging.WARNING)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            cli = make_cli(list(args), run=False, cli_class=ParseOnly)
            with warnings.catch_warnings():  # skip_none: deprecated by jsonargparse 4.49, as cli.RunConfig uses it
                warnings.simplefilter("ignore")
                text = cli.parser.dump(cli.config, skip_none=False, skip_validation=True)
    except SystemExit:
        lines = [line for line in err.getvalue().splitlines() if line.strip()]
        line = next((x for x in lines if "error:" in x), lines[0] if lines else "does not parse")
        raise SweepError(f"{entry}: {line.split('error:', 1)[-1].strip()}") from None
    finally:
        seed_log.setLevel(level)
    config = yaml.safe_load(text)
    for key in VOLATILE:
        _drop(config, key)
    return config


def _config_args(files: list[str], entry: str) -> list[str]:
    out = []
    for f in files:
        path = Path(f)
        if not path.is_file():
            raise SweepError(f"{entry}: config file {f} does not exist")
        out += ["--config", str(path.resolve())]
    return out


_PLACEHOLDER = "<scene_dir>"


def resolved_for_scene(args: list[str], scene_dir: str, entry: str, cache: dict) -> dict:
    """`resolved_config` of `args`, whose `--data.init_args.scene_dir` is `scene_dir`: parsed once for every scene with
    the same other arguments (`cache`), since parsing reads no data (a sweep of 13 scenes x 7 models parses 14 times,
    not 91)."""
    key = tuple(_PLACEHOLDER if a == scene_dir else a for a in args)
    if key not in cache:
        cache[key] = resolved_config(list(key), entry)
    return _with(cache[key], data__init_args__scene_dir=scene_dir)


def _scene_args(scene: SceneEntry) -> list[str]:
    return [*scene.args, "--data.init_args.scene_dir", str(Path(scene.path).resolve())]


def _with(config: dict, **values) -> dict:
    """A copy of a resolved config with `dotted.key=value` set (the view count and seed of one unit)."""
    config = copy.deepcopy(config)
    for dotted, value in values.items():
        *path, last = dotted.split("__")
        node = config
        for key in path:
            node = node.setdefault(key, {})
        node[last] = value
    return config


def build_plan(sweep: Sweep, sweep_file: str | Path | None = None, check_scenes: bool = True) -> Plan:
    """The sweep's units, in stage order, every model config parsed and every folder checked (SweepError naming the
    entry otherwise). Nothing is written. Without `check_scenes` (a dry run, e.g. writing SLURM scripts on a machine
    without the data) a missing scene or reference-depth folder is a warning of the plan instead."""
    warnings: list[str] = []
    cache: dict = {}
    out = Path(sweep.output).resolve()
    group = sweep.wandb.group or sweep.name
    units: list[Unit] = []

    def logger(folder: Path, key: str, tags: list[str]) -> list[str]:
        return ["--trainer.logger.init_args.save_dir", str(folder), "--trainer.logger.init_args.project",
                sweep.wandb.project, "--trainer.logger.init_args.group", group, "--trainer.logger.init_args.name",
                f"{sweep.name}/{key}", "--trainer.logger.init_args.tags", json.dumps(tags),
                "--trainer.logger.init_args.id", f"{slug(sweep.name)[:24]}-{digest_of(str(folder))[:12]}"]

    for i, scene in enumerate(sweep.scenes):
        problems = []
        if not Path(scene.path).is_dir():
            problems.append(f"scenes[{i}]: scene folder {scene.path} does not exist")
        ref = scene.reference_depth
        if ref not in (None, SCENE_DEPTH, NO_DEPTH) and not Path(ref).is_dir():
            problems.append(f"scenes[{i}] ({scene_name(scene)}): reference_depth folder {ref} does not exist")
        if problems and check_scenes:
            raise SweepError(problems[0])
        warnings += problems

    # dense -> depth, per scene (RealEstate-10K: per scene and view count, `split_views`)
    depth_of: dict[tuple[str, int], tuple[str | None, str, str | None]] = {}  # -> (folder, digest, depth unit id)
    for i, scene in enumerate(sweep.scenes):
        name = scene_name(scene)
        if scene.reference_depth is not None:
            given = scene.reference_depth
            folder = None if given in (SCENE_DEPTH, NO_DEPTH) else str(Path(given).resolve())
            for n in sweep.views:
                depth_of[(name, n)] = (folder, digest_of("given", folder), None)
            continue
        files = configs_for(sweep.dense.configs, scene.format)
        entry = f"scenes[{i}] ({name}): dense"
        if not files:
            raise SweepError(f"{entry}: the sweep has no dense.configs for format {scene.format} (or give the scene a "
                             "reference_depth folder)")
        base = [*_config_args(files, entry), *_scene_args(scene), *sweep.dense.args]
        if sweep.dense.max_steps is not None:
            base += ["--trainer.max_steps", str(sweep.dense.max_steps)]
        per_views = scene.format == "realestate"
        split = ["--data.init_args.split_views", str(sweep.views[0])] if per_views else []
        config = resolved_for_scene([*base, *split], str(Path(scene.path).resolve()), entry, cache)
        for n in sweep.views if per_views else [None]:
            key = f"{name}/{n}v" if per_views else name
            folder = out / "dense" / key
            extra_args = ["--data.init_args.split_views", str(n)] if per_views else []
            digest = digest_of(_with(config, data__init_args__split_views=n) if per_views else config)
            args = [*base, *extra_args, "--data.init_args.sparse_depth_cache", str(out / "cache" / "sparse_depth"),
                    "--trainer.default_root_dir", str(folder)]
            labels = {"scene": name, "views": f"all ({n})" if n else "all", "model": "dense", "seed": ""}
            dense = Unit("dense", key, str(folder), digest, args, logger(folder, key, [name, "dense"]), [],
                         labels, {"max_steps": sweep.dense.max_steps or config.get("trainer", {}).get("max_steps")})
            depth = Unit("depth", key, str(folder), digest, args, [], [dense.id], labels,
                         {"out": str(folder / "depth")})
            units += [dense, depth]
            for v in sweep.views if not per_views else [n]:
                depth_of[(name, v)] = (str(folder / "depth"), digest, depth.id)

    # fits and tests; the masks use the first model's data settings
    fits, tests, masks = [], [], {}
    for i, scene in enumerate(sweep.scenes):
        name = scene_name(scene)
        for j, model in enumerate(sweep.models):
            entry = f"models[{j}] ({model.name}) on scenes[{i}] ({name})"
            files = configs_for(model.configs, scene.format)
            if not files:
                raise SweepError(f"{entry}: the model has no configs for format {scene.format}")
            base = [*_config_args(files, entry), *_scene_args(scene), *model.args]
            if sweep.budget.max_steps is not None:
                base += ["--trainer.max_steps", str(sweep.budget.max_steps)]
            n0, s0 = sweep.views[0], sweep.seeds[0]
            first = [*base, "--data.init_args.n_views", str(n0), "--seed_everything", str(s0), "--data.init_args.seed",
                     str(s0)]
            config = resolved_for_scene(first, str(Path(scene.path).resolve()), entry, cache)
            max_steps = config.get("trainer", {}).get("max_steps")
            evaluation = config.get("evaluation") or {}
            for n in sweep.views:
                ref_folder, ref_digest, ref_unit = depth_of[(name, n)]
                if (name, n) not in masks and scene.reference_depth != NO_DEPTH:
                    folder = out / "masks" / name / f"{n}v"
                    key = f"{name}/{n}v"
                    masks[(name, n)] = Unit(
                        "masks", key, str(folder), digest_of(ref_digest, n, config.get("data")),
                        [*base, "--data.init_args.n_views", str(n), "--trainer.default_root_dir", str(folder),
                         "--data.init_args.reference_depth_dir", ref_folder or "null"],
                        [], [ref_unit] if ref_unit else [], {"scene": name, "views": str(n), "model": "", "seed": ""},
                        {"out": str(folder), "scene_dir": str(Path(scene.path).resolve())})
                for s in sweep.seeds:
                    key = f"{name}/{n}v/{slug(model.name)}/seed{s}"
                    folder = out / "runs" / key
                    digest = digest_of(_with(config, data__init_args__n_views=n, seed_everything=s,
                                             data__init_args__seed=s))
                    args = [*base, "--data.init_args.n_views", str(n), "--seed_everything", str(s),
                            "--data.init_args.seed", str(s), "--data.init_args.sparse_depth_cache",
                            str(out / "cache" / "sparse_depth"), "--trainer.default_root_dir", str(folder)]
                    labels = {"scene": name, "views": str(n), "model": model.name, "seed": str(s)}
                    log = logger(folder, key, [name, f"{n}v", model.name, f"seed{s}"])
                    fit = Unit("fit", key, str(folder), digest, args, log, [], labels, {"max_steps": max_steps})
                    test_args = [*args, "--data.init_args.reference_depth_dir", ref_folder or "null"]
                    mask = masks.get((name, n))
                    heldout = sweep.heldout_depth and scene.format == "llff"
                    test = Unit("test", key, str(folder),
                                digest_of(digest, ref_digest, *(["heldout_depth"] if heldout else [])), test_args, log,
                                [fit.id, *([mask.id] if mask else [])], labels,
                                {"format": scene.format, "row": model.name if len(sweep.seeds) == 1
                                 else f"{model.name} (seed {s})", "masks": mask.folder if mask else None,
                                 "lpips": evaluation.get("lpips", True),
                                 "lpips_weights": evaluation.get("lpips_weights")})
                    if heldout:  # the SfM reference is cached beside the sparse depth (`simplenerf heldout-depth`)
                        test.extra.update(heldout_depth=str(folder / "heldout_depth.json"),
                                          heldout_cache=str(out / "cache" / "sparse_depth"))
                    fits.append(fit)
                    tests.append(test)
    units += list(masks.values()) + fits + tests
    table = Unit("table", sweep.name, str(out), digest_of([t.digest for t in tests], sweep.tables), [], [],
                 [t.id for t in tests], {"scene": "", "views": "", "model": "", "seed": ""},
                 {"runs": [[t.extra["format"], t.extra["row"], t.folder, t.key, t.extra["masks"]] for t in tests],
                  "tables": sweep.tables, "scores": sweep.scores,
                  "sweep_file": str(Path(sweep_file).resolve()) if sweep_file else None})
    units.append(table)
    for unit in units:
        # torch's threads in the job: SLURM gives it cpus_per_job CPUs; locally nothing else bounds it, and
        # concurrent_jobs jobs of all-cores threads each would fight for the cores (fern images_4, 2 jobs on 2 cores:
        # 425 rays/s instead of about 1600 in the first steps)
        unit.extra["cpus"] = sweep.resources.for_stage(unit.stage).cpus_per_job
        if sweep.wandb.mode is not None:
            unit.extra["wandb_mode"] = sweep.wandb.mode
    check_folders(units)
    return Plan(sweep, out, units, warnings)


def check_folders(units: list[Unit]) -> None:
    """A folder holding a dense NeRF or a fit of another config stops the sweep: a run folder never mixes two configs
    (delete the folder, or give the sweep another output)."""
    for unit in units:
        if unit.stage not in ("dense", "fit"):
            continue
        state = read_state(Path(unit.folder), unit.stage)
        folder = Path(unit.folder)
        if state is not None and state.get("digest") != unit.digest:
            raise SweepError(f"{unit.stage} {unit.key}: {folder} holds a run of another config (digest "
                             f"{state.get('digest')}, this sweep's {unit.digest}; its config: {folder / 'config.yaml'})"
                             ": delete that folder to retrain it, or give the sweep another output folder")
        if state is None and any((folder / "checkpoints").glob("*.ckpt")):
            raise SweepError(f"{unit.stage} {unit.key}: {folder} has checkpoints the sweep did not write: move them "
                             "away or give the sweep another output folder")


def link_reused(plan: Plan, log=print) -> list[str]:
    """Fits of this sweep whose digest is a done fit in one of `sweep.reuse`'s output folders (their `sweep.json`):
    this sweep's run folder gets a link to that run's checkpoints (`checkpoints -> <other run>/checkpoints`) and a fit
    state `done` naming it (`reused_from`), so the fit is not trained again; its test runs here, into this sweep's
    folder (the other sweep's folder is only read). Returns the linked unit ids."""
    import json
    import os

    from simplenerf.experiments.state import write_state

    done: dict[str, Path] = {}
    for other in plan.sweep.reuse:
        manifest = Path(other) / "sweep.json"
        if not manifest.is_file():
            plan.warnings.append(f"reuse: {other} has no sweep.json (not a sweep folder, or not run yet): nothing "
                                 "reused from it")
            continue
        for unit in json.loads(manifest.read_text())["units"]:
            state = read_state(Path(unit["folder"]), "fit") if unit["stage"] == "fit" else None
            if state and state.get("status") == "done" and state.get("digest") == unit["digest"]:
                done.setdefault(unit["digest"], Path(unit["folder"]))
    linked = []
    for unit in plan.stage("fit"):
        source = done.get(unit.digest)
        folder = Path(unit.folder)
        if source is None or source.resolve() == folder.resolve() or read_state(folder, "fit") is not None:
            continue
        folder.mkdir(parents=True, exist_ok=True)
        if not (folder / "checkpoints").exists():
            os.symlink(source.resolve() / "checkpoints", folder / "checkpoints", target_is_directory=True)
        state = dict(read_state(source, "fit") or {})
        state.update(reused_from=str(source.resolve()), key=unit.key)
        write_state(folder, "fit", state)
        linked.append(unit.id)
        log(f"  fit {unit.key}: reused from {source} (the same settings digest {unit.digest})")
    return linked
