"""Times full-frame rendering of test views (the data module's predict frames, in order); prints ONE JSON line, e.g.

    python -m benchmarks.speed.render --config configs/llff.yaml --frames 1 \
        [--ckpt_path runs/llff/checkpoints/last.ckpt] --data.init_args.scene_dir ../shared/data/nerf_llff_data/fern

The first test view of fern at factor 4 is frame 0, 1008x756 = 762048 rays. The JSON holds s/frame (median, min,
max, all), rays/s, field evaluations/s (coarse + (coarse + fine) samples per ray: 256 in the paper config), peak RSS
and peak CUDA memory. Without --ckpt_path the weights are the initial ones: the same work per ray, other pictures. Rays
per forward pass: `--model.chunk` (after `--`). `--warmup W` renders W untimed frames first.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time
from pathlib import Path

import lightning as L
import torch
from torch.utils.data import DataLoader

from benchmarks.speed.training_step import (
    cpu_seconds,
    cuda_peaks,
    device_name,
    field_evaluations_per_ray,
    matmul_flop_per_ray,
    measuring_trainer,
    peak_rss_gib,
    spread,
    synchronize,
)
from simplenerf.commands import split_overrides
from simplenerf.commands.benchmark import build, emit, measurement_parser, record_header, stdout_to_stderr


class FrameTimer(L.Callback):
    """Wall time and size of every rendered frame of `trainer.predict`."""

    def __init__(self) -> None:
        self.seconds: list[float] = []
        self.cpu_s: list[float] = []
        self.rays: list[int] = []
        self.shape: tuple[int, ...] | None = None
        self._start = 0.0
        self._cpu = 0.0

    def on_predict_start(self, trainer, pl_module) -> None:
        if pl_module.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(pl_module.device)

    def on_predict_batch_start(self, trainer, pl_module, batch, batch_idx, dataloader_idx=0) -> None:
        synchronize(pl_module)
        self._start, self._cpu = time.perf_counter(), cpu_seconds()

    def on_predict_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        synchronize(pl_module)
        self.seconds.append(time.perf_counter() - self._start)
        self.cpu_s.append(cpu_seconds() - self._cpu)
        rgb = outputs.rgb  # a FrameRender
        self.shape = tuple(rgb.shape[:-1])
        self.rays.append(rgb.numel() // rgb.shape[-1])


def crop_rows(frame, rows: int):
    """The top `rows` rows of a full-frame item (pixels in row-major order): every tensor whose first dimension is
    height * width is cut to rows * width and `height` becomes `rows`. Works on dicts and dataclasses (nested too)."""
    from lightning.fabric.utilities.apply_func import apply_to_collection

    def get(name: str):  # a field of a dataclass item (`Frame`) or a key of a dict item (a user's data module)
        return frame.get(name) if isinstance(frame, dict) else getattr(frame, name, None)

    height, width = get("height"), get("width")
    if height is None or width is None:
        raise TypeError(f"cannot crop a frame of type {type(frame).__name__}: it has no height and width")
    height, width = int(height), int(width)
    rows = min(rows, height)
    pixels, kept = height * width, rows * width
    cut = apply_to_collection(frame, torch.Tensor, lambda t: t[:kept] if t.ndim and t.shape[0] == pixels else t)
    if isinstance(cut, dict):
        cut["height"] = rows
    else:
        cut = dataclasses.replace(cut, height=rows)
    return cut


class _CroppedFrames(torch.utils.data.Dataset):
    def __init__(self, frames: torch.utils.data.Dataset, rows: int) -> None:
        self.frames, self.rows = frames, rows

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int):
        return crop_rows(self.frames[i], self.rows)


def time_rendering(
    model: L.LightningModule,
    datamodule: L.LightningDataModule,
    frames: int,
    warmup: int = 0,
    precision: str = "32-true",
    ckpt: str | None = None,
    accelerator: str = "auto",
    devices: int | str = 1,
    rows: int | None = None,
) -> dict:
    """Renders warmup + frames test views (the data module's predict frames, in order) through `trainer.predict`
    and reports the timed ones: s_per_frame (median; _min, _max, _all), rays_per_s, field evaluations per second,
    peak memory. Without `ckpt` the weights are the initial ones: the same work per ray, other pictures. `rows`:
    render only the top rows of each frame (a quick check of rays/s; the work per ray is the same)."""
    timer = FrameTimer()
    trainer = measuring_trainer(precision, accelerator, devices, limit_predict_batches=warmup + frames,
                                callbacks=[timer])
    if rows is None:
        trainer.predict(model, datamodule=datamodule, ckpt_path=ckpt, return_predictions=False)
    else:
        datamodule.setup("predict")
        loader = DataLoader(_CroppedFrames(datamodule.predict_dataloader().dataset, rows), batch_size=None)
        trainer.predict(model, dataloaders=loader, ckpt_path=ckpt, return_predictions=False)
    timed, rays = timer.seconds[warmup:], timer.rays[warmup:]
    if not timed:
        raise RuntimeError(f"no frame left to time: {len(timer.seconds)} rendered, {warmup} warm-up")
    per_ray = field_evaluations_per_ray(model, training=False)
    seconds = sum(timed)
    return {
        "frames_timed": len(timed),
        "frame_shape": list(timer.shape or ()),
        "rays_per_frame": statistics.median(rays),
        **spread(timed, "s_per_frame"),
        "warmup_s": [round(v, 4) for v in timer.seconds[:warmup]],
        "cpu_s_per_frame": statistics.median(timer.cpu_s[warmup:]),
        "rays_per_s": sum(rays) / seconds,
        "field_evaluations_per_ray": per_ray,
        "field_evaluations_per_s": per_ray * sum(rays) / seconds,
        "approx_matmul_tflops": matmul_flop_per_ray(model, training=False) * sum(rays) / seconds / 1e12,
        "chunk": model.hparams.get("chunk"),
        "peak_rss_gib": peak_rss_gib(),
        **cuda_peaks(model.device),
        "device": device_name(model.device),
    }


def main(argv: list[str] | None = None) -> dict:
    own, overrides = split_overrides(sys.argv[1:] if argv is None else argv)
    parser = measurement_parser(__doc__, prog="python -m benchmarks.speed.render")
    parser.add_argument("--ckpt_path", dest="ckpt", old=("--ckpt",), default=None,
                        help="trained weights (default: initial weights, same cost)")
    parser.add_argument("--frames", type=int, default=1, help="timed frames (test views in order)")
    parser.add_argument("--warmup", type=int, default=0, help="untimed frames first")
    parser.add_argument("--rows", type=int, default=None, help="render only the top ROWS rows (a quick rays/s check)")
    args = parser.parse_args(own)
    if args.ckpt is not None and not Path(args.ckpt).is_file():
        parser.error(f"checkpoint {args.ckpt} does not exist")
    with stdout_to_stderr():
        cli = build(args, overrides)
        result = time_rendering(cli.model, cli.datamodule, args.frames, args.warmup, args.precision, args.ckpt,
                                args.accelerator, rows=args.rows)
    record = {**record_header("render", args, overrides), "ckpt": args.ckpt, "warmup": args.warmup, "rows": args.rows,
              **result}
    emit(record)
    return record


if __name__ == "__main__":
    main()
