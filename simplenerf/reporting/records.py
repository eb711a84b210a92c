"""Test scores as records, and the paper's averaging: the frames of tested runs and of the authors' release folders,
pooled into one mean per model and view count over ALL test frames of its scenes.

Pipeline: `NAME=RUN_DIR` arguments -> `expand_runs` -> `load_records` (one `Record` per scene of a model and view
count: the per-frame scores of a tested run's `test/metrics.csv`, or of one scene of an authors' release folder) ->
`mean_rows` (one `Row` per model: per view count, the mean over ALL test frames of the model's scenes, as the paper
averages) or `per_scene_rows` (the scenes' frame means). `tables` lays the rows out.

Averaging: the paper's numbers are the means over all test frames of all scenes, not the means of the scene means
(the authors' QA_Scores.json, reproduced to the last digit by `paper_scores.release_summary`); with unequal numbers
of test frames per scene (LLFF: 3-8) the two differ. Frames without a score (an empty visibility mask, the SROCC of a
constant depth) are left out of that score's mean, as the authors' pandas means leave NaN out.

Sources: a run folder tested by `python -m simplenerf test` (its `test/summary.json` names the scene and view count,
its `test/metrics.csv` holds the frames), or a folder in the layout of the authors' `runs/testing/<test>/` (QA_Scores/
with per-frame CSVs; `paper_scores.read_release_folder`), e.g. ../shared/reference_scores/test1011, whose view count
comes from `paper_scores.RELEASE_VIEWS` or a `@N` suffix (`ours/test2011@2`). A release folder may be given without
NAME: its row is then `RELEASE_MODEL`.

Repeats: several runs of one model on the same scene and view count (e.g. seeds) are its repeats; the r-th run of each
scene (in the order given, sorted for a glob) make repeat r, and a row's value is the mean over its repeats of their
frame means (with the same scenes in every repeat, the mean over all their frames), with the sample standard
deviation over the repeats beside it.

A "key" is a field of summary.json (`masked_lpips`, `lpips`, ...), or of `<run>/heldout_depth.json` (the depth error
at held-out SfM points, `simplenerf heldout-depth`: one value per run, averaged over runs). This module imports no
torch or Lightning.
"""

from __future__ import annotations

import csv
import glob
import json
import math
import re
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from simplenerf.errors import DataError
from simplenerf.reporting.paper_scores import RELEASE_VIEWS, is_release_folder, read_release_folder

METRICS = ("lpips", "ssim", "psnr")
DEPTH_METRICS = ("depth_mae", "depth_srocc")
# Every score of the shared summary.json format, full-frame then masked.
KEYS = (*METRICS, *DEPTH_METRICS, *(f"masked_{m}" for m in (*METRICS, *DEPTH_METRICS)))
# The held-out SfM depth error of a run (`<run>/heldout_depth.json`: its fields rel_error_mean, rel_error_median).
HELDOUT_KEYS = ("heldout_rel_error_mean", "heldout_rel_error_median")
ALL_KEYS = (*KEYS, *HELDOUT_KEYS)
RELEASE_MODEL = "SimpleNeRF (release)"
"""The row name of an authors' release folder given without NAME=."""


@dataclass(frozen=True)
class Record:
    """The test frames of one model on one scene with one number of train views: per key, the frames' scores."""

    model: str
    scene: str
    n_views: int
    frames: dict[str, tuple[float, ...]]  # every key of ALL_KEYS -> the scores of the frames that have it (maybe none)
    path: Path  # the file the scores were read from

    @property
    def scores(self) -> dict[str, float | None]:
        """The scene's mean of every key over its frames that have it (None where none has)."""
        return {k: math.fsum(v) / len(v) if v else None for k, v in self.frames.items()}


@dataclass(frozen=True)
class Row:
    """One table row. `values[(n_views, key)]` is the mean over the frames of the scenes `scenes[n_views]` (absent:
    no value), `frames[(n_views, key)]` how many frames it averages; `spread[(n_views, key)]` the sample standard
    deviation over the model's repeats (absent with one run per scene), `runs[n_views]` how many repeats; `printed`
    gives a value as published (the paper's digits), `paper` marks a published reference row."""

    model: str
    values: dict[tuple[int, str], float]
    scenes: dict[int, tuple[str, ...]]
    printed: dict[tuple[int, str], str] = field(default_factory=dict)
    paper: bool = False
    frames: dict[tuple[int, str], int] = field(default_factory=dict)
    spread: dict[tuple[int, str], float] = field(default_factory=dict)
    runs: dict[int, int] = field(default_factory=dict)

    @property
    def label(self) -> str:
        if self.paper:
            return f"{self.model} (paper)"
        repeats = sorted({k for k in self.runs.values() if k > 1})
        if not repeats:
            return self.model
        return f"{self.model} ({repeats[0] if len(repeats) == 1 else f'{repeats[0]}-{repeats[-1]}'} runs)"


def unique(items: Iterable[str]) -> list[str]:
    """The items without repeats, in first-seen order."""
    return list(dict.fromkeys(items))


def _release_path(text: str) -> tuple[Path, int | None]:
    """A release folder argument: the folder and the view count of its `@N` suffix (None without one)."""
    match = re.fullmatch(r"(.*)@(\d+)", text)
    return (Path(match.group(1)), int(match.group(2))) if match else (Path(text), None)


def expand_runs(args: Sequence[str]) -> list[tuple[str, Path]]:
    """`NAME=RUN_DIR` arguments -> (name, run folder) pairs in the order given. A RUN_DIR with glob characters
    (`runs/llff/*`, quoted so the shell leaves it) stands for the folders it matches, sorted by path. An authors'
    release folder (`paper_scores.is_release_folder`, optionally with an `@N` view-count suffix) may come without
    NAME=: its name is then `RELEASE_MODEL`."""
    runs = []
    for arg in args:
        name, sep, pattern = arg.partition("=")
        if not sep and is_release_folder(_release_path(arg)[0]):
            runs.append((RELEASE_MODEL, Path(arg)))
            continue
        if not sep or not name or not pattern:
            raise DataError(f"{arg!r}: expected NAME=RUN_DIR, e.g. SimpleNeRF=runs/fern_2v or SimpleNeRF='runs/llff/*'"
                            " (or the folder of an authors' test run, e.g. ../shared/reference_scores/test1011)")
        if any(c in pattern for c in "*?["):
            matches = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_dir())
            if not matches:
                raise DataError(f"{pattern}: no run folder matches this pattern (given for {name})")
            runs.extend((name, path) for path in matches)
        else:
            runs.append((name, Path(pattern)))
    return runs


def _read_frames(file: Path) -> dict[str, tuple[float, ...]]:
    """Key -> the finite scores of the frames of a metrics.csv (blank cells: no score)."""
    try:
        with open(file, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        raise DataError(f"{file}: cannot be read ({e})") from None
    frames: dict[str, list[float]] = {key: [] for key in KEYS}
    for row in rows:
        for key in KEYS:
            text = (row.get(key) or "").strip()
            if not text:
                continue
            try:
                value = float(text)
            except ValueError:
                raise DataError(f"{file}: \"{key}\" of frame {row.get('frame')!r} should be a number, found "
                                f"{text!r}") from None
            if math.isfinite(value):
                frames[key].append(value)
    return {key: tuple(values) for key, values in frames.items()}


def load_record(model: str, path: Path) -> Record:
    """The frames of one tested run: `path` is a run folder (reads its test/summary.json for the scene and view count
    and test/metrics.csv for the frames) or its test output folder."""
    path = Path(path)
    file = path / "summary.json" if (path / "summary.json").is_file() else path / "test" / "summary.json"
    if not file.is_file():
        raise DataError(f"{file} not found: test the run first with `python -m simplenerf test --config ... "
                        f"--ckpt_path last` (run folder {path}, given for {model})")
    try:
        summary = json.loads(file.read_text())
    except json.JSONDecodeError as e:
        raise DataError(f"{file}: not valid JSON ({e})") from None
    if not isinstance(summary, dict):
        raise DataError(f"{file}: expected a JSON object with the test summary")
    scene, n_views = summary.get("scene"), summary.get("n_views")
    if not isinstance(scene, str) or not scene or type(n_views) is not int or n_views < 1:
        raise DataError(f"{file}: expected \"scene\" (the scene folder name) and \"n_views\" (a positive integer), "
                        f"found scene={scene!r}, n_views={n_views!r}; re-run `python -m simplenerf test ...` with the "
                        "current code to rewrite it")
    metrics = file.parent / "metrics.csv"
    if not metrics.is_file():
        raise DataError(f"{metrics} not found: the table averages the frames of metrics.csv, which `python -m "
                        "simplenerf test` writes beside summary.json; re-run the test")
    return Record(model, scene, n_views, {**_read_frames(metrics), **_read_heldout(file.parent.parent)}, metrics)


def _read_heldout(run: Path) -> dict[str, tuple[float, ...]]:
    """The held-out SfM depth error of `<run>/heldout_depth.json` as one value per key (none without that file)."""
    file = run / "heldout_depth.json"
    if not file.is_file():
        return {key: () for key in HELDOUT_KEYS}
    try:
        result = json.loads(file.read_text())
        return {key: (float(result[key.removeprefix("heldout_")]),) for key in HELDOUT_KEYS}
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise DataError(f"{file}: expected the JSON of `simplenerf heldout-depth --out` ({e})") from None


def load_release(model: str, path: Path) -> list[Record]:
    """One record per scene of an authors' release folder (`paper_scores.read_release_folder`), scenes in file order;
    its view count comes from an `@N` suffix of `path`, else from `paper_scores.RELEASE_VIEWS` by folder name."""
    folder, n_views = _release_path(str(path))
    n_views = n_views if n_views is not None else RELEASE_VIEWS.get(folder.name)
    if n_views is None:
        raise DataError(f"{folder}: how many train views? The release's folders {', '.join(RELEASE_VIEWS)} are known; "
                        f"name it as {folder}@N")
    scores = [s for s in read_release_folder(folder) if s.key is not None]
    records = []
    for scene in unique(scene for s in scores for scene in s.scenes):
        frames = {key: () for key in ALL_KEYS}
        for s in scores:
            pairs = zip(s.scenes, s.values, strict=True)
            frames[s.key] = tuple(v for at, v in pairs if at == scene and math.isfinite(v))
        records.append(Record(model, scene, n_views, frames, folder / "QA_Scores"))
    return records


def load_records(runs: Sequence[tuple[str, Path]]) -> list[Record]:
    """The records of (model name, run or release folder) pairs, in order. Several runs of one model on the same scene
    and view count are its repeats (module docstring)."""
    records: list[Record] = []
    for model, path in runs:
        release = is_release_folder(_release_path(str(path))[0])
        records += load_release(model, path) if release else [load_record(model, path)]
    return records


def repeats(records: Sequence[Record]) -> list[list[Record]]:
    """The records of one model and view count as repeats: repeat r holds the r-th record of each scene. Every scene
    must have the same number of runs."""
    by_scene: dict[str, list[Record]] = {}
    for record in records:
        by_scene.setdefault(record.scene, []).append(record)
    if len({len(runs) for runs in by_scene.values()}) > 1:
        first = records[0]
        counts = ", ".join(f"{len(runs)} of {scene}" for scene, runs in by_scene.items())
        raise DataError(f"{first.model} with {first.n_views} views has {counts}: give every scene the same number of "
                        "runs (e.g. one per seed), or give some of them another NAME")
    return [list(repeat) for repeat in zip(*by_scene.values(), strict=True)]


def mean_rows(records: Sequence[Record]) -> list[Row]:
    """One row per model (in order of first appearance): per view count, each score averaged over ALL the frames of
    the model's scenes with that view count (the paper's averaging); with repeats, the mean and standard deviation of
    the repeats' such means. A score some of those scenes have no frame of has no mean (see `coverage_warnings`)."""
    rows = []
    for model in unique(r.model for r in records):
        own = [r for r in records if r.model == model]
        values: dict[tuple[int, str], float] = {}
        spread: dict[tuple[int, str], float] = {}
        counts: dict[tuple[int, str], int] = {}
        scenes: dict[int, tuple[str, ...]] = {}
        runs: dict[int, int] = {}
        for n in sorted({r.n_views for r in own}):
            group = [r for r in own if r.n_views == n]
            scenes[n] = tuple(unique(r.scene for r in group))
            repeated = repeats(group)
            runs[n] = len(repeated)
            for key in ALL_KEYS:
                if all(r.frames[key] for r in group):
                    means = [math.fsum(v for r in run for v in r.frames[key]) / sum(len(r.frames[key]) for r in run)
                             for run in repeated]
                    values[(n, key)] = math.fsum(means) / len(means)
                    counts[(n, key)] = sum(len(r.frames[key]) for r in group)
                    if len(means) > 1:
                        spread[(n, key)] = statistics.stdev(means)
        rows.append(Row(model, values, scenes, frames=counts, spread=spread, runs=runs))
    return rows


def per_scene_rows(records: Sequence[Record]) -> dict[str, list[Row]]:
    """Scene (in order of first appearance) -> one row per model with that scene's scores (its frame means)."""
    return {scene: mean_rows([r for r in records if r.scene == scene]) for scene in unique(r.scene for r in records)}


def coverage_warnings(records: Sequence[Record], keys: Sequence[str]) -> list[str]:
    """What makes the means of `mean_rows` not comparable: per view count, models averaged over different scene sets
    (naming each missing (model, scene, views)); and scenes lacking a shown key that the model's other scenes have."""
    warnings = []
    for n in sorted({r.n_views for r in records}):
        group = [r for r in records if r.n_views == n]
        present = {(r.model, r.scene) for r in group}
        missing = [(m, s) for m in unique(r.model for r in group) for s in unique(r.scene for r in group)
                   if (m, s) not in present]
        if missing:
            warnings.append(f"{n} views: models are averaged over different scenes; missing runs: "
                            + ", ".join(f"({m}, {s}, {n} views)" for m, s in missing))
    for model in unique(r.model for r in records):
        for n in sorted({r.n_views for r in records if r.model == model}):
            group = [r for r in records if r.model == model and r.n_views == n]
            for r in group:
                lacking = [k for k in keys if r.scores[k] is None and any(o.scores[k] is not None for o in group)]
                if lacking:
                    warnings.append(f"{model}, {n} views: {r.scene} has no {', '.join(lacking)} ({r.path}), so "
                                    f"{'that mean is' if len(lacking) == 1 else 'those means are'} left out")
    return warnings
