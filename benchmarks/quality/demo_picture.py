"""The README's picture from the demo's two tested runs (`make demo`): one held-out frame of the synthetic scene as
[photo | SimpleNeRF's render | SimpleNeRF's depth | DS-NeRF's depth | exact depth], the depths in one colour range
(that of the exact depth; near = warm), each panel enlarged `--zoom` times, e.g.

    python -m benchmarks.quality.demo_picture runs/grid_demo runs/grid_demo_dsnerf --out docs/images/demo.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from simplenerf.data.llff import load_llff_scene
from simplenerf.viz.pictures import colorize_depth, to_uint8, write_png


def panel(picture: np.ndarray, label: str, zoom: int) -> np.ndarray:
    """An RGB uint8 panel [H, W, 3] enlarged `zoom` times (nearest: the pixels stay visible) under a label bar."""
    big = cv2.resize(picture, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    bar = np.full((22, big.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([bar, big], axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("simplenerf_run")
    parser.add_argument("dsnerf_run")
    parser.add_argument("--scene", default="data/synthetic/objects_seed0_96x128_20",
                        help="the demo's scene folder (written by its first fit)")
    parser.add_argument("--frame", default="008", help="test frame name (default: 008)")
    parser.add_argument("--zoom", type=int, default=2)
    parser.add_argument("--out", default="docs/images/demo.png")
    args = parser.parse_args()
    simple, ds = Path(args.simplenerf_run) / "test", Path(args.dsnerf_run) / "test"
    scene = load_llff_scene(args.scene, factor=1, n_views=3)  # exact depth in the runs' units (scaled)
    index = [Path(name).stem for name in scene.views.names].index(args.frame)
    exact = scene.views.depths[index].numpy()
    inv = 1.0 / exact
    lo, hi = float(np.percentile(inv, 1)), float(np.percentile(inv, 99))
    panels = [
        panel(to_uint8(scene.views.images[index].numpy()), "photo (held out)", args.zoom),
        panel(cv2.cvtColor(cv2.imread(str(simple / "rgb" / f"{args.frame}.png")), cv2.COLOR_BGR2RGB), "SimpleNeRF",
              args.zoom),
        panel(colorize_depth(np.load(simple / "depth" / f"{args.frame}.npy"), lo, hi), "SimpleNeRF depth", args.zoom),
        panel(colorize_depth(np.load(ds / "depth" / f"{args.frame}.npy"), lo, hi), "DS-NeRF depth", args.zoom),
        panel(colorize_depth(exact, lo, hi), "exact depth", args.zoom),
    ]
    gap = np.full((panels[0].shape[0], 4, 3), 255, np.uint8)
    row = np.concatenate([p for item in panels for p in (item, gap)][:-1], axis=1)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_png(Path(args.out), row)
    print(args.out)


if __name__ == "__main__":
    main()
