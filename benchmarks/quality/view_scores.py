"""A trained run's renders of its training views and of its test views, scored alike (docs/results.md "Where the blur
and the streaks come from"): a render as blurred on the views it was trained on as on the held-out ones is an under-fit
(budget, capacity); sharp on the training views and blurred on the others is geometry. Each view's streak index
(`benchmarks.quality.streak_index`: the render's row / column roughness ratio over the photo's; 1: none), and its depth
map's (`depth_streak`), are given too, so that streaks can be judged on validation views, and both against the photo
blurred as much as the render (`streak_matched`, `depth_streak_matched`: blur alone moves the index). With `--spread`,
also how each view's rays spread their weight along the ray: the weighted standard deviation of the fine samples' NDC t
(a uniform fog over [0, 1): 0.29; an opaque surface: about 0), the share of the weight farther than 0.05 in NDC t from
the ray's median, and the footprint in pixels across and down the image (`ray_spread`). With `--surface`, each view is
also scored rendered with the colour at the median of each ray's weights (`surface_render`): what the picture would be
without that blur.

    python -m benchmarks.quality.view_scores runs/grid/fern_seed0_simplerf [--factor 4] [--frames 6,13,16] [--spread] \
        [--surface] [--out DIR] [-- CLI overrides]

The run's config.yaml and checkpoints/last.ckpt (or `--ckpt_path`, e.g. an earlier step's checkpoint) are read;
`--factor` renders at another image size of the same scene. A frame in neither the train nor the test split is a
"validation" view: the place to compare settings without looking at the test frames. Prints one JSON line (per frame
and per kind, train / validation / test: PSNR, LPIPS, and the spread).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.quality.streak_index import axis_ratio, matched_blur
from simplenerf.commands import split_overrides
from simplenerf.data.datasets import Frames
from simplenerf.metrics.lpips import LPIPS
from simplenerf.metrics.scores import lpips, psnr, to_uint8
from simplenerf.run.cli import make_cli


def weight_median(t: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """[R, 1] the t of each ray's sample where its normalised weights p [R, S] reach half their sum."""
    return torch.gather(t, 1, (p.cumsum(-1) < 0.5).sum(-1, keepdim=True).clamp(max=t.shape[1] - 1))


def ray_spread(model, frame, every: int = 37) -> dict[str, float]:
    """Weight spread of every `every`-th ray of a frame: mean weighted std of NDC t, share of weight off-surface, and
    the footprint: the weighted std of the samples' NDC x and y in pixels of the frame's size (NDC x and y span
    [-1, 1] across the reference camera's image). A training ray runs along NDC z, so its footprint is about 0 whatever
    its spread; a ray of a camera moved sideways crosses x as it goes, and a render there is the scene blurred by its
    footprint: the horizontal smear of fern's test frames 0 and 8 (docs/results.md "Where the blur and the streaks come
    from", 13)."""
    with torch.no_grad():
        out = model.nerf(frame.rays[torch.arange(0, len(frame.rays), every)], randomized=False)
    t = out.fine_samples.t
    p = out.fine.weights / out.fine.weights.sum(-1, keepdim=True).clamp_min(1e-6)

    def weighted_std(values: torch.Tensor) -> torch.Tensor:
        mean = (p * values).sum(-1, keepdim=True)
        return (p * (values - mean) ** 2).sum(-1).sqrt()

    off = (p * ((t - weight_median(t, p)).abs() > 0.05)).sum(-1)
    positions = out.fine_samples.positions
    return {"spread_t": float(weighted_std(t).mean()), "off_surface": float(off.mean()),
            "footprint_x_px": float(weighted_std(positions[..., 0]).mean()) * frame.width / 2,
            "footprint_y_px": float(weighted_std(positions[..., 1]).mean()) * frame.height / 2}


def surface_render(model, frame, chunk: int = 2048) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The frame rendered as trained ([H, W, 3]), with each ray's colour taken at one point: the fine field's
    colour at the median of the ray's fine weights ([H, W, 3]), and the fine depth as rendered ([H, W]; one render
    gives all three). The first two differ by what the weight spread along the rays does to the picture (from a
    camera moved sideways, a horizontal blur the width of the rays' footprint); where the median is on the surface,
    the second is that surface's colour without the blur."""
    composite, surface, depth, nerf = [], [], [], model.nerf
    with torch.no_grad():
        for start in range(0, len(frame.rays), chunk):
            rays = frame.rays[start : start + chunk]
            out = nerf(rays, randomized=False)
            t, w = out.fine_samples.t, out.fine.weights
            median = weight_median(t, w / w.sum(-1, keepdim=True).clamp_min(1e-6))
            composite.append(out.fine.rgb)
            depth.append(out.fine.depth)
            surface.append(nerf.evaluate(nerf.fine, nerf.make_samples(rays, median)).rgb[:, 0])
    shape = (frame.height, frame.width, 3)
    return torch.cat(composite).reshape(shape), torch.cat(surface).reshape(shape), torch.cat(depth).reshape(shape[:2])


def main() -> None:
    own, overrides = split_overrides(sys.argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--factor", type=int, help="render at images_<factor> (default: the run's)")
    parser.add_argument("--frames", help="comma-separated frame indices (default: train then test)")
    parser.add_argument("--ckpt_path", type=Path, help="the checkpoint to load (default: RUN/checkpoints/last.ckpt)")
    parser.add_argument("--spread", action="store_true", help="also the weight spread along the rays")
    parser.add_argument("--surface", action="store_true",
                        help="also score each view rendered with the colour at the median of each ray's weights")
    parser.add_argument("--out", type=Path, help="write photo | render PNGs here")
    args = parser.parse_args(own)
    cli_args = ["--config", str(args.run / "config.yaml"), "--trainer.logger", "false"]
    if args.factor:
        cli_args += ["--data.init_args.factor", str(args.factor)]
    cli = make_cli(cli_args + overrides, run=False)
    model, data = cli.model, cli.datamodule
    state = torch.load(args.ckpt_path or args.run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    model.load_state_dict(state["state_dict"])
    model.eval()
    data.setup("test")
    split = data.scene.split
    frames = [int(f) for f in args.frames.split(",")] if args.frames else split.train + split.test
    net = LPIPS.from_weights()
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    per_frame = {}
    for frame in Frames(data.scene.views, data.near, frames):
        if args.surface:
            rgb, surface, depth = surface_render(model, frame, model.hparams.chunk)
            rgb, surface = rgb.clamp(0, 1), surface.clamp(0, 1)
        else:
            with torch.no_grad():
                render = model.render_frame(frame)
            rgb, depth = render.rgb.clamp(0, 1), render.depth
        photo = frame.rgb.reshape(frame.height, frame.width, 3)
        photo_u8, rgb_u8 = to_uint8(photo.numpy()), to_uint8(rgb.numpy())
        photo_ratio = axis_ratio(photo_u8)  # the streak index's reference
        soft_ratio = axis_ratio(matched_blur(photo_u8, rgb_u8)[1])  # the photo as blurred as rgb
        rgb_ratio, depth_ratio = axis_ratio(rgb_u8), axis_ratio(depth.numpy())
        kind = "train" if frame.index in split.train else "test" if frame.index in split.test else "validation"
        scores = {"kind": kind, "psnr": psnr(rgb[None], photo[None]).item(),
                  "lpips": lpips(rgb[None], photo[None], net).item(),
                  "streak": rgb_ratio / photo_ratio, "depth_streak": depth_ratio / photo_ratio,
                  "streak_matched": rgb_ratio / soft_ratio, "depth_streak_matched": depth_ratio / soft_ratio}
        if args.surface:
            scores |= {"surface_psnr": psnr(surface[None], photo[None]).item(),
                       "surface_lpips": lpips(surface[None], photo[None], net).item(),
                       "surface_streak": axis_ratio(to_uint8(surface.numpy())) / photo_ratio}
        if args.spread:
            scores |= ray_spread(model, frame)
        per_frame[frame.index] = scores
        print(frame.index, scores, flush=True, file=sys.stderr)
        if args.out:
            picture = to_uint8(torch.cat([photo, rgb] + ([surface] if args.surface else []), dim=1).numpy())
            cv2.imwrite(str(args.out / f"{kind}_{frame.index:03d}.png"), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
    means = {}
    for kind in ("train", "validation", "test"):
        rows = [s for s in per_frame.values() if s["kind"] == kind]
        if rows:
            means[kind] = {k: round(float(np.mean([r[k] for r in rows])), 4) for k in rows[0] if k != "kind"}
    print(json.dumps({"run": str(args.run), "checkpoint": str(args.ckpt_path or "last"), "factor": args.factor,
                      "frames": per_frame, "mean": means}))


if __name__ == "__main__":
    main()
