"""What cutting a plane's sample points into one batch entry per thread is worth (`simplenerf.model.grid.sample_plane`):
times bilinear `grid_sample` forward + backward of one K-Planes plane at P points, as one batch entry (PyTorch's CPU
kernels divide their work by batch entry, so this runs on one core) and as one entry per thread over the same plane
(`expand`; the entries' gradients are summed), alternating, and says which of the two `sample_plane` picks. E.g. the
planes of `configs/grid/simplerf_images4.yaml`'s fine field at its 1280 rays x 64 samples, on 2 threads:

    OMP_NUM_THREADS=2 python -m benchmarks.speed.grid_sample_threads --points 81920 \
        --planes 16x64x64 16x128x128 16x128x256 16x64x1024 16x1024x1024

Points lie along rays as in NDC: per ray a random width coordinate and a random height coordinate, the height
spanning a tenth of the box along the ray's samples (`--layout random`: every point uniform). Set
SIMPLENERF_MALLOC=reuse as for a fit (without it each summed gradient is a fresh allocation, page-faulted in). Prints
a markdown table (median milliseconds over `--reps`), then ONE JSON line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from simplenerf.model.grid import sample_plane, split_points
from simplenerf.run.hardware import cpu, flush_denormals
from simplenerf.run.memory import reuse_freed_memory


def ray_coords(points: int, samples: int, layout: str, generator: torch.Generator) -> torch.Tensor:
    """[points, 2] coordinates in [-1, 1]: `samples` consecutive points per ray (layout "ray"), or uniform."""
    if layout == "random":
        return torch.rand(points, 2, generator=generator) * 2 - 1
    rays = -(-points // samples)
    start = torch.rand(rays, 1, 2, generator=generator) * 1.8 - 0.9
    along = torch.linspace(0, 0.1, samples)[None, :, None] * torch.tensor([0.0, 1.0])
    return (start + along).reshape(-1, 2)[:points]


def timed(plane: torch.Tensor, grid: torch.Tensor, parts: int) -> tuple[float, float]:
    """Seconds of one forward and one backward of `plane` [1, C, H, W] at `grid` [P, 2] cut into `parts` entries."""
    start = time.perf_counter()
    values = sample_plane(plane, grid, parts)
    forward = time.perf_counter()
    values.backward(torch.ones_like(values))
    end = time.perf_counter()
    plane.grad = None
    return forward - start, end - forward


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.speed.grid_sample_threads", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=81920, help="sample points per plane (rays x samples)")
    parser.add_argument("--samples", type=int, default=64, help="samples per ray (layout ray)")
    parser.add_argument("--planes", nargs="+", default=["16x64x64", "16x128x128", "16x64x1024", "16x1024x1024"],
                        help="planes as CxHxW")
    parser.add_argument("--layout", choices=["ray", "random"], default="ray")
    parser.add_argument("--reps", type=int, default=7, help="timed repetitions of each (after one untimed)")
    args = parser.parse_args(argv)
    flush_denormals()
    reuse_freed_memory()  # SIMPLENERF_MALLOC=reuse, as every `simplenerf` entry point
    threads = torch.get_num_threads()
    generator = torch.Generator().manual_seed(0)
    grid = ray_coords(args.points, args.samples, args.layout, generator)
    rows = []
    print(f"{args.points} points ({args.layout}), {threads} threads, {cpu().line()}\n")
    print("| plane CxHxW | one entry: forward / backward ms | one per thread: forward / backward ms | "
          "sample_plane picks |")
    print("|---|---|---|---|")
    for spec in args.planes:
        channels, height, width = (int(v) for v in spec.split("x"))
        plane = torch.rand(1, channels, height, width, generator=generator, requires_grad=True)
        times: dict[int, list[tuple[float, float]]] = {1: [], threads: []}
        for rep in range(args.reps + 1):
            for parts in ((1, threads) if rep % 2 else (threads, 1)):
                result = timed(plane, grid, parts)
                if rep:
                    times[parts].append(result)
        med = {parts: [1e3 * statistics.median(t[i] for t in runs) for i in (0, 1)] for parts, runs in times.items()}
        picks = split_points(plane, args.points)
        rows.append({"plane": spec, "one_entry_ms": med[1], "per_thread_ms": med[threads], "picks": picks})
        print(f"| {spec} | {med[1][0]:.1f} / {med[1][1]:.1f} | {med[threads][0]:.1f} / {med[threads][1]:.1f} | "
              f"{'one per thread' if picks > 1 else 'one entry'} |")
    record = {"benchmark": "grid_sample_threads", "points": args.points, "layout": args.layout, "threads": threads,
              "torch": torch.__version__, "cpu": cpu().line(), "rows": rows}
    print(json.dumps(record))
    return record


if __name__ == "__main__":
    main()
