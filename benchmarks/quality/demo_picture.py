"""A README picture from two tested runs, SimpleNeRF's and its DS-NeRF baseline's, on one held-out frame:

- a scene with exact depth (the demo's synthetic scene, `make demo`): [photo | SimpleNeRF's render | SimpleNeRF's
  depth | DS-NeRF's depth | exact depth], the depths in the exact depth's colour range;
- a scene without (LLFF): [photo | SimpleNeRF's render | SimpleNeRF's depth | DS-NeRF's render], as issue 33 asks;
  the depth in its own 1st-99th percentile range of inverse depth (near = warm).

Each panel is enlarged `--zoom` times (nearest) or shrunk by `--shrink` (area); `.jpg` writes a JPEG, e.g.

    python -m benchmarks.quality.demo_picture runs/grid_demo runs/grid_demo_dsnerf --out docs/images/demo.png
    python -m benchmarks.quality.demo_picture RUN_SIMPLENERF RUN_DSNERF --scene ../shared/data/nerf_llff_data/fern \
        --factor 4 --frame image008 --zoom 1 --shrink 2 --out docs/images/fern.jpg
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from simplenerf.data.llff import load_llff_scene
from simplenerf.viz.pictures import colorize_depth, inverse_depth_range, to_uint8, write_png


def panel(picture: np.ndarray, label: str, zoom: int, shrink: int = 1) -> np.ndarray:
    """An RGB uint8 panel [H, W, 3] enlarged `zoom` times (nearest: the pixels stay visible) or shrunk `shrink` times
    (area average), under a label bar."""
    if shrink > 1:
        big = cv2.resize(picture, (picture.shape[1] // shrink, picture.shape[0] // shrink),
                         interpolation=cv2.INTER_AREA)
    else:
        big = cv2.resize(picture, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    bar = np.full((22, big.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([bar, big], axis=0)


def read_render(run_test: Path, frame: str) -> np.ndarray:
    path = run_test / "rgb" / f"{frame}.png"
    if not path.is_file():
        raise SystemExit(f"demo_picture: {path} is missing: run `simplenerf test` on that run first")
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def row(photo: np.ndarray, simple_rgb: np.ndarray, simple_depth: np.ndarray, ds: np.ndarray,
        exact: np.ndarray | None = None, zoom: int = 2, shrink: int = 1) -> np.ndarray:
    """The picture [H', W', 3] uint8 from one frame's photo and renders [H, W, 3] uint8 and depths [H, W]: with the
    exact depth, [photo | SimpleNeRF | SimpleNeRF depth | DS-NeRF depth | exact depth] in the exact depth's range,
    `ds` DS-NeRF's depth; without, [photo | SimpleNeRF | SimpleNeRF depth | DS-NeRF] (the depth in its own range),
    `ds` DS-NeRF's render; 4 white pixels between."""
    if exact is not None:
        lo, hi = inverse_depth_range(exact)
        items = [(photo, "photo (held out)"), (simple_rgb, "SimpleNeRF"),
                 (colorize_depth(simple_depth, lo, hi), "SimpleNeRF depth"),
                 (colorize_depth(ds, lo, hi), "DS-NeRF depth"), (colorize_depth(exact, lo, hi), "exact depth")]
    else:
        items = [(photo, "photo (held out)"), (simple_rgb, "SimpleNeRF"),
                 (colorize_depth(simple_depth), "SimpleNeRF depth"), (ds, "DS-NeRF")]
    panels = [panel(picture, label, zoom, shrink) for picture, label in items]
    gap = np.full((panels[0].shape[0], 4, 3), 255, np.uint8)
    return np.concatenate([p for item in panels for p in (item, gap)][:-1], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("simplenerf_run")
    parser.add_argument("dsnerf_run")
    parser.add_argument("--scene", default="data/synthetic/objects_seed0_96x128_20",
                        help="the scene folder (default: the demo's, written by its first fit)")
    parser.add_argument("--factor", type=int, default=1, help="images_<factor> of the scene, as the runs were tested")
    parser.add_argument("--frame", default="008", help="test frame name (default: 008)")
    parser.add_argument("--zoom", type=int, default=2)
    parser.add_argument("--shrink", type=int, default=1, help="shrink each panel this many times (instead of zoom)")
    parser.add_argument("--out", default="docs/images/demo.png", help=".png or .jpg")
    args = parser.parse_args()
    simple, ds = Path(args.simplenerf_run) / "test", Path(args.dsnerf_run) / "test"
    scene = load_llff_scene(args.scene, factor=args.factor, n_views=None)  # any split: only the frames are read
    names = [Path(name).stem for name in scene.views.names]
    if args.frame not in names:
        raise SystemExit(f"demo_picture: no frame {args.frame} in {args.scene} (its frames: {', '.join(names)})")
    index = names.index(args.frame)
    exact = None if scene.views.depths is None else scene.views.depths[index].numpy()
    frame = f"{args.frame}.npy"
    ds_panel = read_render(ds, args.frame) if exact is None else np.load(ds / "depth" / frame)  # the layout's
    picture = row(to_uint8(scene.views.images[index].numpy()), read_render(simple, args.frame),
                  np.load(simple / "depth" / frame), ds_panel, exact, args.zoom, args.shrink)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_png(out, picture, jpeg_quality=85)
    print(out)


if __name__ == "__main__":
    main()
