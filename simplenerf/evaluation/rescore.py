"""Rescoring a tested run from its saved outputs with the current metric and mask definitions
(docs/evaluation.md), without rendering again.

A `test` output folder holds each test frame's prediction (`rgb/<frame>.png`, 8-bit, which is all the metrics use;
`depth/<frame>.npy`, scene units), the visibility mask it was scored over (`mask/<frame>.png`) and `metrics.csv`
(frame name and index per row). The ground truth (images, reference depth) and the train views come from the scene
of the run's config. Each frame is scored twice: over the saved masks (what changed is the metric definitions alone)
and over masks computed now (`visibility.scene_visibility_masks`: the definitions and the masks), so that old,
`saved_masks` and `new` can be compared side by side (`comparison_table`).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np
import torch

from simplenerf.data.scene import Scene
from simplenerf.errors import DataError
from simplenerf.evaluation.evaluator import ALL_METRICS, summarize
from simplenerf.evaluation.visibility import MIN_VIEWS, scene_visibility_masks
from simplenerf.metrics.lpips import LPIPS
from simplenerf.metrics.scores import frame_scores
from simplenerf.viz.pictures import write_mask_png

MASKS = ("saved", "new")
"""The two mask sets a run is rescored over: those saved in its test folder, and those computed now."""


def find_test_folder(path: str | Path) -> Path:
    """The test output folder of `path`: a run folder (its test/) or the test folder itself (it has metrics.csv)."""
    path = Path(path)
    folder = path if (path / "metrics.csv").is_file() else path / "test"
    if not (folder / "metrics.csv").is_file():
        raise DataError(f"{folder / 'metrics.csv'} not found: give a run folder tested by `python -m simplenerf test` "
                        "or its test/ folder")
    return folder


def read_rows(folder: Path) -> list[dict[str, float | str | int | None]]:
    """The rows of `<folder>/metrics.csv`: frame (name), index (int) and every metric (float, None when blank)."""
    with open(folder / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    out = []
    for row in rows:
        scores = {name: float(row[name]) if row.get(name) not in (None, "") else None for name in ALL_METRICS}
        out.append({"frame": row["frame"], "index": int(row["index"]), **scores})
    return out


def _read_png(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DataError(f"{path} is missing or not an image")
    return image


def read_rgb(path: Path) -> torch.Tensor:
    """An 8-bit RGB PNG as float64 [H, W, 3] in [0, 1] (exact levels / 255)."""
    bgr = _read_png(path, cv2.IMREAD_COLOR)
    return torch.from_numpy(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float64) / 255.0)


def read_mask(path: Path) -> torch.Tensor:
    """A mask PNG written by `viz.pictures.write_mask_png` as bool [H, W] (True where white)."""
    return torch.from_numpy(_read_png(path, cv2.IMREAD_GRAYSCALE) > 127)


def saved_masks(folder: Path, rows: list[dict]) -> dict[int, torch.Tensor]:
    """Frame index -> the mask saved in `<folder>/mask/<frame>.png`, for the frames that have one."""
    return {int(r["index"]): read_mask(folder / "mask" / f"{r['frame']}.png") for r in rows
            if (folder / "mask" / f"{r['frame']}.png").is_file()}


def rescore_frames(folder: Path, rows: list[dict], scene: Scene, masks: Mapping[int, torch.Tensor],
                   lpips_net: LPIPS | None) -> list[dict]:
    """The rows scored again from the saved predictions (arguments as in `rescore_run`).

    Returns:
        one row per frame: frame, index and the ten metrics of `metrics.frame_scores`.
    """
    views = scene.views
    rescored = []
    for row in rows:
        index, name = int(row["index"]), str(row["frame"])
        pred = read_rgb(folder / "rgb" / f"{name}.png")
        if tuple(pred.shape[:2]) != (views.height, views.width):
            raise DataError(f"{folder / 'rgb' / name}.png is {tuple(pred.shape[:2])}, the scene's frames "
                            f"{(views.height, views.width)}: the config does not describe this run's scene")
        depth_file = folder / "depth" / f"{name}.npy"
        pred_depth = torch.from_numpy(np.load(depth_file)) if depth_file.is_file() else None
        gt_depth = views.depths[index] if views.depths is not None else None
        scores = frame_scores(pred, views.images[index], pred_depth, gt_depth, lpips_net, masks.get(index))
        rescored.append({"frame": name, "index": index, **scores})
    return rescored


def write_scores(out_dir: Path, stem: str, rows: list[dict], extra: dict) -> dict:
    """Writes `<stem>.csv` (per frame) and `<stem>.json` (the means, `evaluator.summarize`, plus `extra`) into
    `out_dir`; returns the means."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / f"{stem}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["frame", "index", *ALL_METRICS])
        writer.writeheader()
        writer.writerows(rows)
    means = summarize(rows)
    (out_dir / f"{stem}.json").write_text(json.dumps({**extra, "frames": len(rows), **means}, indent=2))
    return means


def rescore_run(folder: Path, scene: Scene, lpips_net: LPIPS | None, out_dir: Path | None = None,
                min_views: int = MIN_VIEWS) -> dict[str, dict]:
    """Scores a test folder's saved frames again over its saved masks and over masks computed now.

    Args:
        folder: a test output folder (`find_test_folder`).
        scene: the run's scene (ground-truth images, reference depth, split), e.g. its data module's `.scene`.
        lpips_net: the LPIPS network, or None to leave LPIPS out.
        out_dir: where the results go (default `<folder>/rescored`): `saved_masks.{csv,json}`, `new.{csv,json}` and
            the new masks as `mask/<frame>.png`.
        min_views: train views that must see a pixel (new masks).

    Returns:
        "old" (the means of the folder's metrics.csv), "saved_masks" and "new" -> metric -> mean (None: no value);
        "new" is absent when the scene has no reference depth (no masks can be computed).
    """
    rows = read_rows(folder)
    out_dir = Path(out_dir) if out_dir is not None else folder / "rescored"
    results = {"old": summarize(rows)}
    source = {"rescored_from": str(folder)}
    rescored = rescore_frames(folder, rows, scene, saved_masks(folder, rows), lpips_net)
    results["saved_masks"] = write_scores(out_dir, "saved_masks", rescored, {**source, "masks": "saved"})
    if scene.views.depths is not None and len(scene.split.train) >= min_views:
        indices = [int(r["index"]) for r in rows]
        masks = scene_visibility_masks(scene.views, scene.split.train, indices, min_views, progress=False)
        (out_dir / "mask").mkdir(parents=True, exist_ok=True)
        for row in rows:
            write_mask_png(out_dir / "mask" / f"{row['frame']}.png", masks[int(row["index"])].cpu().numpy())
        rescored = rescore_frames(folder, rows, scene, masks, lpips_net)
        results["new"] = write_scores(out_dir, "new", rescored, {**source, "masks": "new"})
    return results


def comparison_table(results: Mapping[str, Mapping[str, float | None]]) -> str:
    """A markdown table: one row per metric, one column per result of `rescore_run` (4 decimals, "-" for none)."""
    names = list(results)
    lines = ["| metric | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for metric in ALL_METRICS:
        cells = [f"{results[n][metric]:.4f}" if results[n].get(metric) is not None else "-" for n in names]
        lines.append(f"| {metric} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
