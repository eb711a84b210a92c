"""How far each camera of a scene sees past the grid's box (docs/results.md, "Where the blur and the streaks come
from", 36).

A forward-facing scene's NDC x and y are [-1, 1] across the reference (average) camera's image; the other cameras sit
to its sides and turn, so their frusta reach past it. `KPlanesField` spans [-extent_x, extent_x] x [-extent_y,
extent_y] and a point outside takes the planes' border values, the same for every x past the edge: seen from a
camera that looks past it, a horizontal streak (a vertical one past y). For each frame this prints its frustum's NDC
x and y range (the image's four corners at the near plane, NDC t = 0, and at infinity, t = 1) and its split; with
`--run RUN`, for each test frame rendered in RUN/test/depth/, the share of pixels per vertical strip whose rendered
surface lies outside the box of RUN's fine field.

    python -m benchmarks.quality.ndc_extent configs/grid/simplerf_images4.yaml [--run RUN] [--strips 4] \
        [-- --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern]

The first argument is a config (a run's config.yaml names its scene); what follows `--` overrides it. Prints one JSON
line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from benchmarks.quality.streak_index import frame_index
from simplenerf.commands import split_overrides
from simplenerf.geometry.rays import pixel_grid
from simplenerf.geometry.views import Views


def frustum_extent(views: Views, near: float) -> torch.Tensor:
    """[V, 4] (x min, x max, y min, y max) in NDC of each view's frustum: the rays through its image's four outer
    corners (pixel centres are integers, so the corners are at -0.5 and size - 0.5), at NDC t = 0 and t = 1."""
    w, h, count = views.width, views.height, len(views)
    corners = torch.tensor([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]).repeat(count, 1)
    rays = views.rays(torch.arange(count).repeat_interleave(4), corners, near)
    ends = torch.stack([rays.ndc_origins, rays.ndc_origins + rays.ndc_directions], dim=1)[..., :2]  # [4 V, 2, 2]
    ends = ends.reshape(count, 8, 2)
    return torch.stack([ends[..., 0].amin(1), ends[..., 0].amax(1), ends[..., 1].amin(1), ends[..., 1].amax(1)], -1)


def surface_ndc(views: Views, view: int, depth: np.ndarray) -> np.ndarray:
    """[H, W, 2] NDC x, y of the surface each pixel of `view` renders at camera z-depth `depth` [H, W]."""
    uv = pixel_grid(views.height, views.width).to(views.c2w.dtype)
    origins, directions = views.pixel_rays(torch.full((uv.shape[0],), view), uv)
    points = origins + torch.from_numpy(depth.reshape(-1)).to(origins.dtype)[:, None] * directions
    scale = torch.stack([-2.0 * views.intrinsics[view, 0, 0] / views.width,
                         -2.0 * views.intrinsics[view, 1, 1] / views.height])
    return (scale * points[:, :2] / points[:, 2:]).reshape(views.height, views.width, 2).numpy()


def outside_share(xy: np.ndarray, extent: tuple[float, float], strips: int) -> list[float]:
    """Per vertical strip of equal width (left to right), the share of pixels whose NDC x, y [H, W, 2] lie outside
    [-extent_x, extent_x] x [-extent_y, extent_y]."""
    outside = (np.abs(xy[..., 0]) > extent[0]) | (np.abs(xy[..., 1]) > extent[1])
    edges = np.linspace(0, xy.shape[1], strips + 1).round().astype(int)
    return [float(outside[:, a:b].mean()) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def main() -> None:
    from simplenerf.run.cli import load_for_tool

    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", help="a config, e.g. a run's config.yaml")
    parser.add_argument("--run", type=Path, help="a run folder whose test/depth/*.npy to place against the box")
    parser.add_argument("--strips", type=int, default=4)
    args = parser.parse_args(own)
    cli = load_for_tool([args.config], overrides)
    scene, near = cli.datamodule.scene, cli.datamodule.near
    fine = cli.model.nerf.fine
    extent = tuple(getattr(fine, "extent", (1.0, 1.0)))
    split = {**{i: "test" for i in scene.split.test}, **{i: "train" for i in scene.split.train}}
    result: dict = {"config": args.config, "extent": list(extent), "frames": [
        {"frame": i, "split": split.get(i, "other"), "x": [round(float(v), 3) for v in row[:2]],
         "y": [round(float(v), 3) for v in row[2:]]}
        for i, row in enumerate(frustum_extent(scene.views, near))]}
    if args.run is not None:
        depths = sorted((args.run / "test" / "depth").glob("*.npy"))
        if not depths:
            raise SystemExit(f"{args.run / 'test' / 'depth'} has no .npy depth maps: run `simplenerf test` first")
        result["outside"] = {}
        for path in depths:
            frame = frame_index(path.stem, scene.views.names)
            xy = surface_ndc(scene.views, frame, np.load(path))
            result["outside"][path.stem] = [round(v, 4) for v in outside_share(xy, extent, args.strips)]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
