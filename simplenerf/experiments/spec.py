"""The sweep file: a YAML checked by jsonargparse against these dataclasses (an unknown key or a wrong type stops the
sweep with one line naming it, before anything runs).

A sweep is scenes x view counts x models x seeds (the paper's Tables 1-3: 8 LLFF scenes and RealEstate-10K, 2 / 3 / 4
views, SimpleNeRF, DS-NeRF and the ablations), plus a dense reference NeRF per scene for the depth metrics and the
visibility masks (Sec. 5.1, "a NeRF model with dense input views", trained on all non-test frames), the budget, the
executor's
resources and where everything goes. `simplenerf.experiments.plan` turns it into jobs.

Formats: a scene's `format` (`llff`, `realestate`) picks, in every model and in the dense entry, the config files of
that format (`configs: {llff: [...], realestate: [...]}`), since a config names its data module; a plain list serves
every format.
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

from jsonargparse import ArgumentParser, Namespace

from simplenerf.errors import SimpleNeRFError

FORMATS = ("llff", "realestate")
EXECUTORS = ("slurm", "local", "debug")
STAGES = ("dense", "depth", "masks", "fit", "test", "table")
WANDB_MODES = ("online", "offline", "disabled")
SCENE_DEPTH = "scene"
"""`reference_depth: scene`: the scene's own depth (`<scene>/depths_<factor>/`, e.g. the synthetic scene's exact
depth), no dense NeRF."""
NO_DEPTH = "none"
"""`reference_depth: none`: the sweep makes no reference depth (no dense NeRF, no visibility-mask job): the tests score
full frames (a scene's own depth maps, where it has them, are still read by the test). With `heldout_depth`, an LLFF
scene's depth is scored at held-out SfM points instead."""
SCORES = ("masked", "full", "both")  # simplenerf.reporting.tables.SCORES


class SweepError(SimpleNeRFError):
    """A sweep file, or an entry of it, that cannot run; the message names the entry."""


@dataclass
class SceneEntry:
    """One scene of the sweep."""

    path: str
    """The scene folder (LLFF: holds poses_bounds.npy and images_N/; RealEstate-10K: <id>.txt and frames/)."""
    format: str = "llff"
    """llff or realestate: which of a model's config lists applies."""
    name: str | None = None
    """Its name in folders and tables (default: the folder's name, as test/summary.json records it)."""
    args: list[str] = field(default_factory=list)
    """CLI overrides for this scene in every job, e.g. ["--data.init_args.factor", "1"]."""
    reference_depth: str | None = None
    """A folder of reference depth (<frame>.npy, `simplenerf export-depth`'s output) instead of a dense NeRF;
    `scene`: the scene's own depth (depths_<factor>/); `none`: none (no dense NeRF, no visibility-mask job: full-frame
    scores, NO_DEPTH); null: the sweep trains the dense NeRF."""


@dataclass
class ModelEntry:
    """One model (a table row): config files and overrides."""

    name: str
    """Its row in the results table; the paper's names (SimpleNeRF, DS-NeRF, w/o points augmentation, ...) sit beside
    the published rows."""
    configs: list[str] | dict[str, list[str]]
    """Config files in order (later ones override), or per scene format {llff: [...], realestate: [...]}."""
    args: list[str] = field(default_factory=list)
    """CLI overrides for this model in every fit, e.g. ["--model.objective.sparse_depth_weight", "0.2"]."""


@dataclass
class DenseEntry:
    """The dense reference NeRF (configs/dense/): trained on every non-test frame; its depth of every frame is the
    reference of the depth metrics and the visibility masks. LLFF: one per scene (its test frames do not depend on the
    view count); RealEstate-10K: one per scene and view count (`split_views n`, configs/dense/realestate.yaml)."""

    configs: list[str] | dict[str, list[str]] = field(default_factory=dict)
    """Config files, or per scene format."""
    args: list[str] = field(default_factory=list)
    """CLI overrides of every dense fit."""
    max_steps: int | None = None
    """Training steps of a dense NeRF (null: its config's)."""


@dataclass
class Budget:
    """How long each fit trains."""

    max_steps: int | None = None
    """Training steps of every fit (null: each config's). Warm-up and LR decay are the configs' (give a shorter
    schedule in a model's configs when shortening a run)."""


@dataclass
class StageResources:
    """One stage's resources where they differ from the sweep's (`resources.stages.<stage>`); null keeps the value
    of the stage's default (STAGE_DEFAULTS), else the sweep's."""

    gpus_per_job: int | None = None
    cpus_per_job: int | None = None
    mem_gb: float | None = None
    time_limit_min: int | None = None
    partition: str | None = None
    account: str | None = None
    concurrent_jobs: int | None = None
    setup: list[str] | None = None
    """Replaces the sweep's setup lines for this stage."""
    slurm_args: dict[str, str] | None = None
    """Added to (and overriding) the sweep's slurm_args for this stage."""


STAGE_DEFAULTS: dict[str, dict] = {
    # The visibility masks are numpy on the CPU (simplenerf.evaluation.visibility) and the table reads JSON files:
    # neither holds a GPU. dense, depth, fit and test use the GPU and take the sweep's resources as they are.
    "masks": {"gpus_per_job": 0},
    "table": {"gpus_per_job": 0, "cpus_per_job": 1, "mem_gb": 4, "time_limit_min": 30},
}
"""Per stage, what differs from the sweep's `resources` unless the sweep file's `resources.stages` says otherwise."""


@dataclass
class Resources:
    """What each job gets, and how many run at once: the values of the GPU stages (dense, depth, fit, test); the
    masks and the table have defaults of their own (STAGE_DEFAULTS: no GPU), and `stages` overrides any stage."""

    gpus_per_job: int = 0
    """GPUs per job (SLURM --gpus-per-node; local: that many of this machine's GPUs per job, CUDA_VISIBLE_DEVICES;
    0: a CPU job)."""
    cpus_per_job: int = 1
    """CPUs per job (SLURM --cpus-per-task) and the job's torch threads (local jobs too)."""
    mem_gb: float | None = None
    """Memory per job in GB (SLURM --mem; null: the partition's default)."""
    time_limit_min: int = 60
    """Wall-time limit of one job in minutes (SLURM --time); a fit cut by it is requeued by Lightning and resumes."""
    partition: str | None = None
    """SLURM partition."""
    account: str | None = None
    """SLURM account."""
    concurrent_jobs: int = 1
    """Jobs of a stage running at once (SLURM: the array's %N; local: parallel processes)."""
    setup: list[str] = field(default_factory=list)
    """Shell lines run before each SLURM job (e.g. `source .venv/bin/activate`)."""
    slurm_args: dict[str, str] = field(default_factory=dict)
    """More sbatch options, e.g. {qos: high, constraint: a100}."""
    stages: dict[str, StageResources] = field(default_factory=dict)
    """Per stage (dense, depth, masks, fit, test, table), what differs, e.g. {masks: {partition: cpu, cpus_per_job:
    4}, fit: {time_limit_min: 720}}."""

    def __post_init__(self) -> None:
        self.stages = {k: v if isinstance(v, StageResources) else StageResources(**(v or {}))
                       for k, v in (self.stages or {}).items()}

    def for_stage(self, stage: str) -> Resources:
        """The resources of one stage's jobs: the sweep's, then the stage's defaults, then `stages.<stage>`."""
        values = {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self) if f.name != "stages"}
        values.update(STAGE_DEFAULTS.get(stage, {}))
        own = self.stages.get(stage)
        if own is not None:
            for f in fields(own):
                value = getattr(own, f.name)
                if value is None:
                    continue
                values[f.name] = {**values["slurm_args"], **value} if f.name == "slurm_args" else copy.deepcopy(value)
        return Resources(**values)


@dataclass
class Wandb:
    """W&B: every run of the sweep is in one group, tagged with its scene, views, model and seed."""

    project: str = "simplenerf-sweeps"
    group: str | None = None
    """The runs' group (default: the sweep's name)."""
    mode: str | None = None
    """online, offline or disabled: every job's WANDB_MODE. A SLURM sweep must say it (the pre-flight stops without
    it, or without WANDB_MODE in the environment): offline when the compute nodes cannot reach W&B (then `wandb sync`
    the runs' wandb/ folders from a machine that can)."""


@dataclass
class Sweep:
    """Scenes x views x models x seeds, with their dense references, tests and the results table."""

    name: str
    """The sweep's name (W&B group, job names)."""
    output: str
    """The sweep folder: run folders, dense references, masks, job logs and the results table go there."""
    scenes: list[SceneEntry]
    views: list[int]
    """Numbers of train views (the paper: 2, 3, 4)."""
    models: list[ModelEntry]
    seeds: list[int] = field(default_factory=lambda: [0])
    dense: DenseEntry = field(default_factory=DenseEntry)
    budget: Budget = field(default_factory=Budget)
    resources: Resources = field(default_factory=Resources)
    executor: str = "local"
    """slurm, local (this machine, `resources.concurrent_jobs` at a time) or debug (in this process, one by one)."""
    tables: dict[str, str] = field(default_factory=dict)
    """Per scene format, the paper's table the results sit beside (simplenerf.reporting.paper_scores.TABLES: llff,
    realestate, llff-ablations, realestate-ablations)."""
    wandb: Wandb = field(default_factory=Wandb)
    reuse: list[str] = field(default_factory=list)
    """Output folders of other sweeps: a fit whose digest (its resolved config) is done there is linked into this sweep
    instead of trained again (its checkpoints; the test runs here), e.g. the ablations' SimpleNeRF rows from Table 1."""
    heldout_depth: bool = False
    """Every test of an LLFF scene also scores the depth at held-out SfM points (`<run>/heldout_depth.json`, what
    `simplenerf heldout-depth --out` writes; the table's held-out columns): the depth score of a real scene without
    reference depth (`reference_depth: none`)."""
    scores: str = "masked"
    """The table's scores: masked (the paper's: pixels seen by at least two train views), full (full frames: scenes
    without reference depth have no masks) or both."""


def sweep_parser() -> ArgumentParser:
    parser = ArgumentParser(prog="simplenerf sweep", exit_on_error=False)
    parser.add_class_arguments(Sweep, as_group=False)
    return parser


def slug(text: str) -> str:
    """A folder name for `text`: letters, digits, '.', '-' and '_' kept, runs of anything else become '_'."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "_"


def configs_for(entry_configs: list[str] | dict[str, list[str]], fmt: str) -> list[str] | None:
    """The config files of one format (None when the entry has none for it)."""
    if isinstance(entry_configs, dict):
        return list(entry_configs[fmt]) if fmt in entry_configs else None
    return list(entry_configs)


def load_sweep(path: str | Path, base: Path | None = None) -> Sweep:
    """The sweep file at `path`, checked: SweepError with one line on an unknown key, a wrong type or an impossible
    value. Relative paths in it (output, scenes, configs, reference depth) are relative to `base` (default: the
    current folder, as the CLI's config paths are)."""
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"sweep file {path} does not exist")
    parser = sweep_parser()
    try:
        cfg = parser.parse_path(str(path), defaults=True)
        # jsonargparse renamed instantiate_classes to instantiate; either version works.
        sweep = (parser.instantiate if hasattr(parser, "instantiate") else parser.instantiate_classes)(cfg)
    except Exception as e:  # jsonargparse's ArgumentError: nested causes, the first line names the key
        from simplenerf.run.console import parser_error_line  # the key, then its innermost cause

        raise SweepError(f"{path}: {parser_error_line(str(e), parser)[0].removeprefix('--') or type(e).__name__}"
                         ) from None
    sweep = _as_sweep(sweep)
    check_values(sweep, path)
    return sweep


def _as_sweep(obj) -> Sweep:
    """jsonargparse gives the top level as a Namespace of instantiated parts; build the Sweep from it."""
    if isinstance(obj, Sweep):
        return obj
    values = obj.as_dict() if isinstance(obj, Namespace) else dict(obj)
    values = {k: v for k, v in values.items() if k != "__path__" and k != "config"}
    return Sweep(**{k: _part(k, v) for k, v in values.items()})


def _part(key: str, value):
    kinds = {"dense": DenseEntry, "budget": Budget, "resources": Resources, "wandb": Wandb}
    if key in kinds and isinstance(value, dict):
        return kinds[key](**value)
    if key == "scenes":
        return [v if isinstance(v, SceneEntry) else SceneEntry(**v) for v in value]
    if key == "models":
        return [v if isinstance(v, ModelEntry) else ModelEntry(**v) for v in value]
    return value


def check_values(sweep: Sweep, path: Path) -> None:
    """What the types cannot say: known formats and executor, positive counts, unique names."""
    from simplenerf.reporting.paper_scores import TABLES

    if sweep.executor not in EXECUTORS:
        raise SweepError(f"{path}: executor {sweep.executor!r} is not one of {', '.join(EXECUTORS)}")
    for i, scene in enumerate(sweep.scenes):
        if scene.format not in FORMATS:
            raise SweepError(f"{path}: scenes[{i}] ({scene.path}): format {scene.format!r} is not one of "
                             f"{', '.join(FORMATS)}")
    for what, items in (("scenes", sweep.scenes), ("views", sweep.views), ("models", sweep.models),
                        ("seeds", sweep.seeds)):
        if not items:
            raise SweepError(f"{path}: {what} is empty")
    if any(n < 1 for n in sweep.views):
        raise SweepError(f"{path}: views {sweep.views}: each must be at least 1")
    names = [scene_name(s) for s in sweep.scenes]
    for what, items in (("scene names", names), ("model names", [slug(m.name) for m in sweep.models]),
                        ("views", sweep.views), ("seeds", sweep.seeds)):
        if len(set(items)) != len(items):
            raise SweepError(f"{path}: {what} repeat ({', '.join(map(str, items))}): give each a distinct one")
    for fmt, table in sweep.tables.items():
        if fmt not in FORMATS or table not in TABLES:
            raise SweepError(f"{path}: tables: {fmt}: {table} (formats: {', '.join(FORMATS)}; tables: "
                             f"{', '.join(TABLES)})")
    if sweep.scores not in SCORES:
        raise SweepError(f"{path}: scores {sweep.scores!r} is not one of {', '.join(SCORES)}")
    if sweep.wandb.mode is not None and sweep.wandb.mode not in WANDB_MODES:
        raise SweepError(f"{path}: wandb.mode {sweep.wandb.mode!r} is not one of {', '.join(WANDB_MODES)}")
    for stage in sweep.resources.stages:
        if stage not in STAGES:
            raise SweepError(f"{path}: resources.stages: {stage!r} is not a stage ({', '.join(STAGES)})")
    for stage in STAGES:
        res = sweep.resources.for_stage(stage)
        where = "resources" if stage not in sweep.resources.stages else f"resources.stages.{stage}"
        if res.concurrent_jobs < 1:
            raise SweepError(f"{path}: {where}.concurrent_jobs must be at least 1")
        if res.gpus_per_job < 0 or res.cpus_per_job < 1 or res.time_limit_min < 1:
            raise SweepError(f"{path}: {where}: gpus_per_job {res.gpus_per_job}, cpus_per_job {res.cpus_per_job}, "
                             f"time_limit_min {res.time_limit_min}: expected gpus >= 0, cpus >= 1, minutes >= 1")


def scene_name(scene: SceneEntry) -> str:
    return scene.name or Path(scene.path).name
