"""How much of the picture's texture a run prints into its depth, on the demo's synthetic scene (exact depth known;
every surface there is a plane). Scored on the test frames, on "flat" pixels: those whose 3 x 3 neighbourhood lies on
one plane (the exact inverse depth, affine in the pixel coordinates on a plane, has second differences below
`--flat-tol` of its value). Among them, "textured" pixels are those where the photo has an edge (grey-level gradient
magnitude in the top `--edge-quantile` of the flat pixels') and "plain" pixels the rest. A depth that is wrong but
smooth on a plane has a smooth error; printed texture makes the error jump where the photo does. So, with
e = (z - z_exact) / z_exact the relative error and |grad e| its gradient magnitude (central differences):

- `flat_error`: mean |e| on the flat pixels;
- `flat_roughness`: mean |grad e| on the flat pixels (0 for an exact or a smoothly wrong plane);
- `textured_roughness`, `plain_roughness`: the same on the textured and on the plain flat pixels;
- `texture_ratio` = textured_roughness / plain_roughness: 1 when the depth's jumps do not follow the picture's,
  above 1 when they do.

    python -m benchmarks.quality.texture_in_depth runs/grid_demo runs/grid_demo_dsnerf
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from simplenerf.data.llff import load_llff_scene


def flat_pixels(exact: np.ndarray, tol: float) -> np.ndarray:
    """[H, W] bool: pixels whose 3 x 3 neighbourhood is on one plane of the exact depth [H, W] (border: False)."""
    inv = 1.0 / exact
    flat = np.zeros_like(exact, dtype=bool)
    d_rows = np.abs(inv[2:, 1:-1] - 2 * inv[1:-1, 1:-1] + inv[:-2, 1:-1])
    d_cols = np.abs(inv[1:-1, 2:] - 2 * inv[1:-1, 1:-1] + inv[1:-1, :-2])
    d_diag = np.abs(inv[2:, 2:] - inv[2:, :-2] - inv[:-2, 2:] + inv[:-2, :-2])
    flat[1:-1, 1:-1] = np.maximum(np.maximum(d_rows, d_cols), d_diag) < tol * inv[1:-1, 1:-1]
    return flat


def gradient_magnitude(values: np.ndarray) -> np.ndarray:
    """[H, W] gradient magnitude (central differences; border 0) of [H, W] values."""
    strength = np.zeros_like(values)
    strength[1:-1, 1:-1] = np.hypot(values[1:-1, 2:] - values[1:-1, :-2], values[2:, 1:-1] - values[:-2, 1:-1]) / 2
    return strength


def score(depth: np.ndarray, exact: np.ndarray, image: np.ndarray, flat_tol: float, edge_quantile: float
          ) -> dict[str, float]:
    """The scores of one frame: depth [H, W], exact depth [H, W], photo [H, W, 3] in [0, 1]."""
    flat = flat_pixels(exact, flat_tol)
    error = (depth - exact) / exact
    roughness = gradient_magnitude(error)
    edges = gradient_magnitude(image.mean(axis=-1))
    textured = flat & (edges >= np.quantile(edges[flat], 1.0 - edge_quantile))
    plain = flat & ~textured
    return {"flat_error": float(np.abs(error[flat]).mean()), "flat_roughness": float(roughness[flat].mean()),
            "textured_roughness": float(roughness[textured].mean()),
            "plain_roughness": float(roughness[plain].mean()), "flat_fraction": float(flat.mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="run folders with test/depth/<frame>.npy (a `test` of the demo)")
    parser.add_argument("--scene", default="data/synthetic/objects_seed0_96x128_20",
                        help="the demo's scene folder (written by its first fit)")
    parser.add_argument("--flat-tol", type=float, default=1e-3)
    parser.add_argument("--edge-quantile", type=float, default=0.2)
    args = parser.parse_args()
    scene = load_llff_scene(args.scene, factor=1, n_views=3)  # exact depth in the runs' units (scaled)
    names = [Path(name).stem for name in scene.views.names]
    for run in args.runs:
        depths = sorted((Path(run) / "test" / "depth").glob("*.npy"))
        if not depths:
            raise SystemExit(f"{run}: no test/depth/*.npy (run `simplenerf test` on it first)")
        frames = []
        for path in depths:
            i = names.index(path.stem)
            frames.append(score(np.load(path), scene.views.depths[i].numpy(), scene.views.images[i].numpy(),
                                args.flat_tol, args.edge_quantile))
        mean = {key: float(np.mean([f[key] for f in frames])) for key in frames[0]}
        mean["texture_ratio"] = mean["textured_roughness"] / mean["plain_roughness"]
        print(json.dumps({"run": run, "frames": len(frames), **{k: round(v, 4) for k, v in mean.items()}}))


if __name__ == "__main__":
    main()
