"""Streaks along the image axes in a run's test renders and depth maps (docs/results.md "Simple-RF's augmentation on
the grid"): for a map, the mean |difference between neighbouring rows| over the mean |difference between neighbouring
columns|, divided by the same ratio of the held-out photo. 1: as isotropic as the photo; above 1: smeared along rows
(horizontal streaks); below 1: along columns. A frame is matched to the photo of the scene's `images_<factor>`
folder with the same name, else by the index its name ends with (`image008` -> the 9th photo).

    python -m benchmarks.quality.streak_index runs/grid/fern_seed0_simplenerf --scene ../shared/data/nerf_llff_data/fern
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import cv2
import numpy as np


def axis_ratio(values: np.ndarray) -> float:
    """mean |d/d row| / mean |d/d column| of an [H, W] or [H, W, C] map (channels averaged first)."""
    values = values.astype(np.float64)
    if values.ndim == 3:
        values = values.mean(axis=-1)
    return float(np.abs(np.diff(values, axis=0)).mean() / np.abs(np.diff(values, axis=1)).mean())


def streak_index(run: Path, photos: list[Path]) -> dict[str, float]:
    """Mean streak index over the run's test frames, of the depth maps and of the renders."""
    by_name = {p.stem: p for p in photos}
    depth, render = [], []
    for path in sorted((run / "test" / "depth").glob("*.npy")):
        found = re.search(r"(\d+)$", path.stem)
        if path.stem not in by_name and (found is None or int(found.group(1)) >= len(photos)):
            raise SystemExit(f"{path}: no photo of that name, nor an index among the {len(photos)} photos")
        photo_path = by_name.get(path.stem) or photos[int(found.group(1))]
        photo = cv2.imread(str(photo_path))
        if photo is None:
            raise SystemExit(f"{photo_path}: not an image")
        reference = axis_ratio(photo)
        depth.append(axis_ratio(np.load(path)) / reference)
        rgb = cv2.imread(str(run / "test" / "rgb" / f"{path.stem}.png"))
        render.append(axis_ratio(rgb) / reference)
    if not depth:
        raise SystemExit(f"{run}: no test/depth/*.npy (run `simplenerf test` on it first)")
    return {"depth": float(np.mean(depth)), "render": float(np.mean(render)), "frames": len(depth)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="run folders with test/depth/*.npy and test/rgb/*.png")
    parser.add_argument("--scene", required=True, help="the LLFF scene folder the runs were tested on")
    parser.add_argument("--factor", type=int, default=8, help="the images_<factor> the runs were tested at")
    args = parser.parse_args()
    folder = Path(args.scene) / f"images_{args.factor}"
    photos = sorted(p for p in folder.glob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not photos:
        raise SystemExit(f"{folder}: no photos")
    for run in args.runs:
        print(json.dumps({"run": run, **{k: round(v, 3) for k, v in streak_index(Path(run), photos).items()}}))


if __name__ == "__main__":
    main()
