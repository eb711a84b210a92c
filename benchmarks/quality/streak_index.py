"""Streaks along the image axes in a run's test renders and depth maps (docs/results.md "Simple-RF's augmentation on
the grid"): for a map, the mean |difference between neighbouring rows| over the mean |difference between neighbouring
columns|, divided by the same ratio of the held-out photo. 1: as isotropic as the photo; above 1: smeared along rows
(horizontal streaks); below 1: along columns. A frame is matched to the photo of the scene's `images_<factor>`
folder with the same name, else by the index its name ends with (`image008` -> the 9th photo).

`--matched` also divides by the ratio of the photo blurred as much as the render is (`render_matched`, `depth_matched`,
`matched_sigma`): blur alone moves a photo's ratio (fern's test photos, images_4: a Gaussian blur of 4 px raises it by
25%, 93% in the right quarter, with no streak at all; docs/results.md, "Where the blur and the streaks come from", 35),
so the plain index counts blur as streaks on some scenes. The blur is the Gaussian whose photo has the render's mean
|d/d row|, the variation a smear along rows leaves (it takes the column differences); the depth map takes its render's
blur. A render's noise and its streaks' own edges add row variation, so the blur found is if anything too small: where
blur raises the photo's ratio (fern) the matched index is still an upper bound on the streaks.

`--strips N` also gives the index of N vertical strips of equal width, left to right (each strip's ratio over the
photo's ratio in the same strip): where across the frame the streaks are (docs/results.md, "Where the blur and the
streaks come from", 16).

    python -m benchmarks.quality.streak_index runs/grid/fern_seed0_simplenerf --scene ../shared/data/nerf_llff_data/fern
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import cv2
import numpy as np


def axis_variation(values: np.ndarray, axis: int) -> float:
    """mean |difference between neighbours along `axis`| (0: rows, 1: columns) of an [H, W] or [H, W, C] map (channels
    averaged first)."""
    values = values.astype(np.float64)
    if values.ndim == 3:
        values = values.mean(axis=-1)
    return float(np.abs(np.diff(values, axis=axis)).mean())


def axis_ratio(values: np.ndarray) -> float:
    """mean |d/d row| / mean |d/d column| of an [H, W] or [H, W, C] map (channels averaged first)."""
    return axis_variation(values, 0) / axis_variation(values, 1)


def matched_blur(photo: np.ndarray, render: np.ndarray, max_sigma: float = 32.0) -> tuple[float, np.ndarray]:
    """The Gaussian blur (sigma in pixels, to 0.01) after which `photo`'s mean |d/d row| is `render`'s, and the blurred
    photo ([H, W, C] float). 0 (the photo as it is) when the render varies as much as the photo or more; `max_sigma`
    when even that blur leaves the photo more varied. The variation falls as sigma grows (a blur never adds variation),
    so bisection finds it."""
    photo = photo.astype(np.float64)
    target = axis_variation(render, 0)
    if axis_variation(photo, 0) <= target:
        return 0.0, photo
    low, high = 0.0, max_sigma
    at_high = cv2.GaussianBlur(photo, (0, 0), high)
    if axis_variation(at_high, 0) >= target:
        return high, at_high
    while high - low > 0.01:
        mid = 0.5 * (low + high)
        at_mid = cv2.GaussianBlur(photo, (0, 0), mid)
        if axis_variation(at_mid, 0) > target:
            low = mid
        else:
            high, at_high = mid, at_mid
    return high, at_high


def frame_index(stem: str, names: list[str]) -> int:
    """Which of the scene's frames (file `names`, in order) a rendered map named `stem` is of: the file of that name
    (its stem), else the index the name ends with (`image008` -> 8). SystemExit when neither."""
    stems = [Path(name).stem for name in names]
    if stem in stems:
        return stems.index(stem)
    found = re.search(r"(\d+)$", stem)
    if found is None or int(found.group(1)) >= len(names):
        raise SystemExit(f"{stem}: no frame file of that name, nor an index among the {len(names)} frames")
    return int(found.group(1))


def strip_ratios(values: np.ndarray, strips: int) -> np.ndarray:
    """`axis_ratio` of each of `strips` vertical strips of an [H, W] or [H, W, C] map, left to right: [strips]. A strip
    is the columns [i W / strips, (i + 1) W / strips); its column differences stay within it."""
    width = values.shape[1]
    edges = [i * width // strips for i in range(strips + 1)]
    spans = list(zip(edges[:-1], edges[1:], strict=True))
    if min(b - a for a, b in spans) < 2:
        raise SystemExit(f"{strips} strips of a map {width} pixels wide: each strip needs at least 2 columns")
    return np.array([axis_ratio(values[:, a:b]) for a, b in spans])


def streak_index(run: Path, photos: list[Path], strips: int = 0,
                 matched: bool = False) -> dict[str, float | list[float]]:
    """Mean streak index over the run's test frames, of the depth maps and of the renders; with `strips`, also per
    vertical strip (`depth_strips`, `render_strips`: lists left to right); with `matched`, also against the photo
    blurred as much as each render (`render_matched`, `depth_matched`, their `*_strips_matched` with `strips`, and
    the mean `matched_sigma`)."""
    per_frame: dict[str, list] = {}  # each score's value per frame, averaged below

    def add(key: str, value: float | np.ndarray) -> None:
        per_frame.setdefault(key, []).append(value)

    for path in sorted((run / "test" / "depth").glob("*.npy")):
        photo_path = photos[frame_index(path.stem, [p.name for p in photos])]
        photo = cv2.imread(str(photo_path))
        if photo is None:
            raise SystemExit(f"{photo_path}: not an image")
        depth_map = np.load(path)
        rgb = cv2.imread(str(run / "test" / "rgb" / f"{path.stem}.png"))
        depth_ratio, render_ratio, reference = axis_ratio(depth_map), axis_ratio(rgb), axis_ratio(photo)
        add("depth", depth_ratio / reference)
        add("render", render_ratio / reference)
        if strips:
            depth_strips, render_strips = strip_ratios(depth_map, strips), strip_ratios(rgb, strips)
            photo_strips = strip_ratios(photo, strips)
            add("depth_strips", depth_strips / photo_strips)
            add("render_strips", render_strips / photo_strips)
        if matched:
            sigma, soft = matched_blur(photo, rgb)
            soft_ratio = axis_ratio(soft)
            add("matched_sigma", sigma)
            add("depth_matched", depth_ratio / soft_ratio)
            add("render_matched", render_ratio / soft_ratio)
            if strips:
                soft_strips = strip_ratios(soft, strips)
                add("depth_strips_matched", depth_strips / soft_strips)
                add("render_strips_matched", render_strips / soft_strips)
    if not per_frame:
        raise SystemExit(f"{run}: no test/depth/*.npy (run `simplenerf test` on it first)")
    means = {key: np.mean(values, axis=0) for key, values in per_frame.items()}
    means = {key: mean.tolist() if mean.ndim else float(mean) for key, mean in means.items()}
    index = {"depth": means.pop("depth"), "render": means.pop("render"), "frames": len(per_frame["depth"]), **means}
    return index


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="run folders with test/depth/*.npy and test/rgb/*.png")
    parser.add_argument("--scene", required=True, help="the LLFF scene folder the runs were tested on")
    parser.add_argument("--factor", type=int, default=8, help="the images_<factor> the runs were tested at")
    parser.add_argument("--strips", type=int, default=0,
                        help="also the index of this many vertical strips, left to right (0: the whole frame only)")
    parser.add_argument("--matched", action="store_true",
                        help="also against the photo blurred as much as each render (blur alone moves the ratio)")
    args = parser.parse_args()
    folder = Path(args.scene) / f"images_{args.factor}"
    photos = sorted(p for p in folder.glob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not photos:
        raise SystemExit(f"{folder}: no photos")
    for run in args.runs:
        index = streak_index(Path(run), photos, args.strips, args.matched)
        print(json.dumps({"run": run, **{k: np.round(v, 3).tolist() for k, v in index.items()}}))


if __name__ == "__main__":
    main()
