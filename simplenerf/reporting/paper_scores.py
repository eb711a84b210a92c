"""The paper's published scores: the printed tables as data (reference rows for `simplenerf results --paper`), and a
reader of the authors' per-frame scores (`read_release_folder`), which the printed means are the frame means of.

Numbers are strings exactly as printed (so "0.14" keeps its two decimals and a test can compare them with the .tex);
`float()` them to compute. Keys follow the names of `test/summary.json`: `masked_lpips`, `masked_ssim`, `masked_psnr`,
`masked_depth_mae`, `masked_depth_srocc` for scores on the pixels seen by at least two train views, and `lpips`, ...,
`depth_srocc` for full-frame scores.

The paper's main tables are masked scores: the release's runs/testing/test1011/QA_Scores.json gives SimpleNeRF's
masked 2-view LLFF means as PSNR 19.57, SSIM 0.650, LPIPS 0.269, depth MAE 0.142, SROCC 0.848, which are Table 1's
2-view SimpleNeRF row and the depth table's LLFF row. The supplement's full-frame ("values within parenthesis") and
per-scene tables have no body in `paper/SimpleNeRF.tex`; FULL_FRAME and PER_SCENE hold a few of those numbers, rounded
as the paper prints them, from the release's published scores (runs/testing/, a copy in ../shared/reference_scores).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simplenerf.errors import DataError

# The scenes the published means are over (supplement, Database Details; the RealEstate-10K ids: the release's
# src/database_utils/real_estate/data_organizers/VideoNameMapper.py, scenes 0, 1, 3, 4, 6).
LLFF_SCENES = ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex")
REALESTATE_SCENES = ("000c3ab189999a83", "000db54a47bd43fe", "0017ce4c6a39d122", "002ae53df0e0afe2", "0043978734eec081")

# (n_views, summary key) -> value as printed.
Scores = dict[tuple[int, str], str]


@dataclass(frozen=True)
class PaperTable:
    """Published rows of one of the paper's tables (models in the paper's order), over the scenes it averages."""

    label: str
    caption: str
    scenes: tuple[str, ...]
    rows: dict[str, Scores]
    # scene -> model -> scores, for the per-scene tables (only the few in PER_SCENE).
    per_scene: dict[str, dict[str, Scores]] = field(default_factory=dict)


def _columns(views: tuple[int, ...], keys: tuple[str, ...]) -> list[tuple[int, str]]:
    return [(v, k) for v in views for k in keys]


# Tables 1 and 2: LPIPS, SSIM, PSNR at 2, 3 and 4 views, masked.
MAIN_COLUMNS = _columns((2, 3, 4), ("masked_lpips", "masked_ssim", "masked_psnr"))
# tab:quantitative-llff.
LLFF_MAIN = {
    "RegNeRF": ("0.3056", "0.5712", "18.52", "0.2908", "0.6334", "20.22", "0.2794", "0.6645", "21.32"),
    "FreeNeRF": ("0.2638", "0.6322", "19.52", "0.2754", "0.6583", "20.93", "0.2848", "0.6764", "21.91"),
    "DS-NeRF": ("0.3106", "0.5862", "18.24", "0.3031", "0.6321", "20.20", "0.2979", "0.6582", "21.23"),
    "DDP-NeRF": ("0.2851", "0.6218", "18.73", "0.3250", "0.6152", "18.73", "0.3042", "0.6558", "20.17"),
    "ViP-NeRF": ("0.2768", "0.6225", "18.61", "0.2798", "0.6548", "20.54", "0.2854", "0.6675", "20.75"),
    "SimpleNeRF": ("0.2688", "0.6501", "19.57", "0.2559", "0.6940", "21.37", "0.2633", "0.7016", "21.99"),
}
# tab:quantitative-realestate.
REALESTATE_MAIN = {
    "RegNeRF": ("0.4129", "0.5916", "17.14", "0.4171", "0.6132", "17.86", "0.4316", "0.6257", "18.34"),
    "FreeNeRF": ("0.5036", "0.5354", "14.70", "0.4635", "0.5708", "15.26", "0.5226", "0.6027", "16.31"),
    "DS-NeRF": ("0.2709", "0.7983", "26.26", "0.2893", "0.8004", "26.50", "0.3103", "0.7999", "26.65"),
    "DDP-NeRF": ("0.1290", "0.8640", "27.79", "0.1518", "0.8587", "26.67", "0.1563", "0.8617", "27.07"),
    "ViP-NeRF": ("0.0687", "0.8889", "32.32", "0.0758", "0.8967", "31.93", "0.0892", "0.8968", "31.95"),
    "SimpleNeRF": ("0.0635", "0.8942", "33.10", "0.0726", "0.8984", "33.21", "0.0847", "0.8987", "32.88"),
}

# tab:quantitative-depth: depth MAE and SROCC at 2 views, masked; LLFF then RealEstate-10K.
DEPTH_COLUMNS = _columns((2,), ("masked_depth_mae", "masked_depth_srocc"))
DEPTH = {
    "DS-NeRF": (("0.2074", "0.7230"), ("0.7164", "0.6660")),
    "DDP-NeRF": (("0.2048", "0.7480"), ("0.4831", "0.7921")),
    "ViP-NeRF": (("0.1999", "0.7344"), ("0.3856", "0.8446")),
    "SimpleNeRF": (("0.1420", "0.8480"), ("0.3269", "0.9215")),
}

# tab:quantitative-ablations: LPIPS and depth MAE at 2 views, masked; RealEstate-10K then LLFF.
ABLATION_COLUMNS = _columns((2,), ("masked_lpips", "masked_depth_mae"))
ABLATIONS = {
    "SimpleNeRF": (("0.0635", "0.33"), ("0.2688", "0.14")),
    "w/o points augmentation": (("0.0752", "0.38"), ("0.2832", "0.15")),
    "w/o views augmentation": (("0.0790", "0.39"), ("0.2834", "0.15")),
    "w/o coarse-fine consistency": (("0.0740", "0.42"), ("0.3002", "0.19")),
    "w/o reliable depth": (("0.0687", "0.45"), ("0.3020", "0.22")),
    "w/ identical augmentations": (("0.0777", "0.40"), ("0.2849", "0.15")),
    "w/ smaller n/w as points aug": (("0.0740", "0.38"), ("0.2849", "0.15")),
}

# Full-frame SimpleNeRF scores (the supplement's tables, not in the .tex): the release's runs/testing/test1011/
# QA_Scores.json (PSNR02 17.5668, ...) and, per scene, QA_Scores/predicted_frames/PSNR02_SceneWise.csv (LLFF) and
# test0011's PSNR01_SceneWise.csv (scene 0 = 000c3ab189999a83, VideoNameMapper.py), rounded as the paper prints.
FULL_FRAME = {
    "llff": {"SimpleNeRF": {(2, "psnr"): "17.57", (2, "ssim"): "0.553", (2, "lpips"): "0.390",
                            (2, "depth_mae"): "0.278", (2, "depth_srocc"): "0.753"}},
}
PER_SCENE = {
    "llff": {scene: {"SimpleNeRF": {(2, "psnr"): psnr}}
             for scene, psnr in (("fern", "17.01"), ("horns", "17.14"), ("fortress", "22.51"), ("room", "19.52"),
                                 ("trex", "16.83"))},
    "realestate": {"000c3ab189999a83": {"SimpleNeRF": {(2, "psnr"): "31.89"}}},
}


def _main_table(dataset: str, label: str, caption: str, scenes: tuple[str, ...], main: dict, depth_index: int
                ) -> PaperTable:
    rows: dict[str, Scores] = {model: dict(zip(MAIN_COLUMNS, values, strict=True)) for model, values in main.items()}
    for model, values in DEPTH.items():
        rows[model].update(zip(DEPTH_COLUMNS, values[depth_index], strict=True))
    for model, scores in FULL_FRAME.get(dataset, {}).items():
        rows[model].update(scores)
    return PaperTable(label, caption, scenes, rows, PER_SCENE.get(dataset, {}))


def _ablation_table(label: str, caption: str, scenes: tuple[str, ...], index: int) -> PaperTable:
    rows = {model: dict(zip(ABLATION_COLUMNS, values[index], strict=True)) for model, values in ABLATIONS.items()}
    return PaperTable(label, caption, scenes, rows)


TABLES = {
    "llff": _main_table("llff", "tab:quantitative-llff", "Table 1 (LLFF) and the depth table, masked", LLFF_SCENES,
                        LLFF_MAIN, 0),
    "realestate": _main_table("realestate", "tab:quantitative-realestate",
                              "Table 2 (RealEstate-10K) and the depth table, masked", REALESTATE_SCENES,
                              REALESTATE_MAIN, 1),
    "llff-ablations": _ablation_table("tab:quantitative-ablations", "Table 3 (ablations, LLFF), masked",
                                      LLFF_SCENES, 1),
    "realestate-ablations": _ablation_table("tab:quantitative-ablations",
                                            "Table 3 (ablations, RealEstate-10K), masked", REALESTATE_SCENES, 0),
}


# ---------------------------------------------------------------------------------------------------------------------
# The authors' per-frame scores (their release's runs/testing/<test>/, copied to ../shared/reference_scores): a folder
# holds QA_Scores.json and QA_Scores/{predicted_frames,predicted_depths}/<Metric><NN>_FrameWise.csv, one row per test
# frame (scene, frame number, score rounded to 4 decimals). QA_Scores.json holds, per metric, numpy.round(numpy.mean(
# the rounded frame scores of ALL scenes), 4): the paper's table values are means over frames, not over scene means.

RELEASE_GROUPS = ("predicted_frames", "predicted_depths")
"""The sub-folders of a release folder's QA_Scores/ (image metrics, depth metrics)."""

RELEASE_KEYS = {"PSNR": "psnr", "SSIM": "ssim", "LPIPS": "lpips", "DepthMAE": "depth_mae", "DepthSROCC": "depth_srocc"}
"""Release metric names (without the `Masked` prefix and the 2-digit suffix) -> summary keys. The release's RMSE,
DepthRMSE and their masked versions have no summary key: they are read but not tabulated."""

RELEASE_VIEWS = {"test1011": 2, "test1021": 3, "test1031": 4, "test0011": 2, "test0021": 3, "test0031": 4}
"""Train views of the release's SimpleNeRF test folders (../shared/reference_scores/README.md)."""


@dataclass(frozen=True)
class ReleaseFrameScores:
    """One metric of a release folder: per test frame, its scene, frame number and score, in file order."""

    group: str  # "predicted_frames" or "predicted_depths"
    metric: str  # as the release names it, e.g. "MaskedSSIM02"
    scenes: tuple[str, ...]
    frames: tuple[int, ...]
    values: tuple[float, ...]

    @property
    def key(self) -> str | None:
        """The summary key (`masked_ssim`, ...), or None for the release's RMSE metrics."""
        name = self.metric.rstrip("0123456789")
        masked = name.startswith("Masked")
        base = RELEASE_KEYS.get(name.removeprefix("Masked"))
        return None if base is None else ("masked_" if masked else "") + base


def is_release_folder(path: Path) -> bool:
    """Whether `path` is a folder in the release's test layout (it has QA_Scores/ with per-frame CSVs)."""
    return any((Path(path) / "QA_Scores" / group).is_dir() for group in RELEASE_GROUPS)


def read_release_folder(path: Path) -> list[ReleaseFrameScores]:
    """Every `<Metric>_FrameWise.csv` of a release folder, in group then file-name order.

    Raises:
        DataError: if the folder has none, or a file is not three columns (scene, frame number, score) with a header.
    """
    path = Path(path)
    found = []
    for group in RELEASE_GROUPS:
        for file in sorted((path / "QA_Scores" / group).glob("*_FrameWise.csv")):
            with open(file, newline="") as f:
                lines = list(csv.reader(f))
            if not lines or len(lines[0]) != 3 or any(len(line) != 3 for line in lines[1:]):
                raise DataError(f"{file}: expected a header and rows of scene, frame number, score")
            try:
                values = tuple(float(line[2]) for line in lines[1:])
                frames = tuple(int(line[1]) for line in lines[1:])
            except ValueError as e:
                raise DataError(f"{file}: {e}") from None
            found.append(ReleaseFrameScores(group, file.name.removesuffix("_FrameWise.csv"),
                                            tuple(line[0] for line in lines[1:]), frames, values))
    if not found:
        raise DataError(f"{path}: no QA_Scores/{{{','.join(RELEASE_GROUPS)}}}/*_FrameWise.csv (the layout of the "
                        "authors' runs/testing/<test>/ folders, e.g. ../shared/reference_scores/test1011)")
    return found


def release_summary(scores: list[ReleaseFrameScores]) -> dict[str, dict[str, float]]:
    """The QA_Scores.json of per-frame scores: group -> metric -> the mean over all frames, rounded as the release
    rounds it (numpy.round(mean, 4); frames without a score, NaN, are left out as pandas does)."""
    summary: dict[str, dict[str, float]] = {}
    for s in scores:
        values = np.asarray(s.values, dtype=np.float64)
        summary.setdefault(s.group, {})[s.metric] = float(np.round(np.mean(values[~np.isnan(values)]), 4))
    return summary
