"""Evaluation outputs of `test` (and renders of `predict`): images, depths, visibility masks, per-frame CSV and a
summary JSON, following the paper's protocol (Sec. 5.1, supplement Evaluation Details): full-frame scores and scores
over each test frame's
visibility mask (`simplenerf.evaluation.visibility`), when the scene has reference depth.

Everything is written to `<dir>.partial/` first and moved into place only when the run completes, so a crash or a
bad input never leaves half-written files over the results of an earlier run.
"""

from __future__ import annotations

import csv
import functools
import json
import os
import shutil
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import lightning as L
import numpy as np
import torch

from simplenerf.data.scene import Scene, SceneDataModule
from simplenerf.errors import DataError, RunFolderError
from simplenerf.evaluation.visibility import MIN_VIEWS, scene_visibility_masks
from simplenerf.metrics.lpips import LPIPS, LPIPSWeightsNotFound
from simplenerf.metrics.scores import MASKED_METRIC_NAMES, METRIC_NAMES, PSNR_CAP, frame_scores
from simplenerf.model.nerf import FrameRender
from simplenerf.viz.pictures import colorize_depth, write_mask_png, write_png

METRICS = METRIC_NAMES
"""Full-frame metrics of summary.json and metrics.csv."""
MASKED_METRICS = MASKED_METRIC_NAMES
"""The same over the visibility masks (null without reference depth)."""
ALL_METRICS = (*METRICS, *MASKED_METRICS)


def export_visibility_masks(scene: Scene, out_dir: str | Path, min_views: int = MIN_VIEWS) -> dict[str, float]:
    """Writes the visibility mask of every test frame of `scene` as `<out_dir>/<frame>.png` (white = visible) and
    `<out_dir>/<frame>.npy` (bool [H, W]); returns frame name -> visible fraction.

    Raises DataError if the scene has no reference depth (the message names the scene's folder).
    """
    if scene.views.depths is None:
        raise DataError(
            f"scene {scene.source} has no reference depth, which "
            "visibility masks need (e.g. <scene>/depths_<factor>/<frame>.npy): train a dense NeRF "
            "(configs/dense/*.yaml), export its depth with `simplenerf export-depth` and pass the folder as "
            "--data.init_args.reference_depth_dir"
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    masks = scene_visibility_masks(scene.views, scene.split.train, scene.split.test, min_views)
    fractions = {}
    for index, mask in masks.items():
        name = scene.views.names[index]
        array = mask.cpu().numpy()
        write_mask_png(out_dir / f"{name}.png", array)
        np.save(out_dir / f"{name}.npy", array)
        fractions[name] = float(array.mean())
    return fractions


@functools.cache
def git_commit() -> str | None:
    """The commit of the code being run, if it runs from a git checkout (read once per process)."""
    try:
        root = Path(__file__).resolve().parent
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def summarize(rows: list[dict]) -> dict[str, float | None]:
    """Mean of each metric over the frames that have it (None where no frame has it): the masked means run over the
    frames with a visibility mask."""
    summary = {}
    for name in ALL_METRICS:
        values = [r[name] for r in rows if r.get(name) is not None]
        summary[name] = float(np.mean(values)) if values else None
    return summary


def gather_rows(rows: list[dict]) -> list[dict]:
    """The rows of every distributed rank (all ranks must call this), one per frame index, in index order.

    A distributed sampler pads the last batches by repeating frames, so a frame may come from two ranks; its rows are
    identical and the first is kept.
    """
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        parts: list[list[dict] | None] = [None] * torch.distributed.get_world_size()
        torch.distributed.all_gather_object(parts, rows)
        rows = [row for part in parts for row in (part or [])]
    unique: dict[int, dict] = {}
    for row in rows:
        unique.setdefault(int(row["index"]), row)
    return [unique[i] for i in sorted(unique)]


def format_table(rows: list[dict], summary: dict) -> str:
    """A fixed-width text table: one line per frame and a mean line; masked columns only when some frame has them."""
    names = [*METRICS, *(m for m in MASKED_METRICS if summary.get(m) is not None)]
    widths = [max(len(n), 7) + 2 for n in names]
    frame_width = max([len("frame"), len("mean"), *(len(str(r["frame"])) for r in rows)])

    def line(label: str, cells: list[str]) -> str:
        return f"{label:<{frame_width}}" + "".join(f"{c:>{w}}" for c, w in zip(cells, widths, strict=True))

    def values(scores: dict) -> list[str]:
        return [f"{scores[n]:.4f}" if scores.get(n) is not None else "-" for n in names]

    header = line("frame", names)
    body = [line(str(r["frame"]), values(r)) for r in rows]
    return "\n".join([header, *body, "-" * len(header), line("mean", values(summary))])


def archive_path(folder: Path) -> Path:
    """A free name beside `folder` for its earlier contents: `<name>.<YYYYmmdd-HHMMSS>` of the time its run.json says
    it was written (else its modification time), with `-2`, `-3`, ... if taken."""
    written = None
    try:
        written = datetime.fromisoformat(json.loads((folder / "run.json").read_text())["written"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    if written is None:
        written = datetime.fromtimestamp(folder.stat().st_mtime, timezone.utc)
    base = folder.with_name(f"{folder.name}.{written.astimezone(timezone.utc).strftime('%Y%m%d-%H%M%S')}")
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path


def _scene(trainer: L.Trainer) -> Scene | None:
    """The scene of the trainer's data module (None: a data module of another kind, or none)."""
    datamodule = trainer.datamodule
    return datamodule.scene if isinstance(datamodule, SceneDataModule) else None


class Evaluator(L.Callback):
    """Scores and saves every rendered test frame; saves renders of `predict`.

    Output folder (default `<trainer.default_root_dir>/test`): `rgb/<frame>.png`, `depth/<frame>.npy` (metric depth,
    scene units), `depth/<frame>.png` (colourised), `mask/<frame>.png` (the visibility mask, white = evaluated),
    `metrics.csv` (one row per frame: frame, index, then the ten metric names), `summary.json` (scene, n_views, frames,
    the means of the ten metrics, checkpoint, git_commit, config), `config.yaml` (the config this test ran with, from
    the CLI; else a copy of the run's, when there is one) and `run.json`. A folder of earlier results is kept, renamed
    `<folder>.<time it was written>` (`archive_path`).

    Scores (Sec. 5.1): psnr, ssim, lpips, depth_mae, depth_srocc over the full frame, and masked_* over the frame's
    visibility mask. Masks are computed at test setup from the data module's scene (`.scene.views` with reference
    depth, `.scene.split.train`) and exist only when the scene has reference depth; otherwise, and for an empty
    mask, the masked scores are null. Depth metrics need reference depth too. A score that cannot be computed (e.g.
    SROCC of a constant depth map) is null, and means run over the frames that have the score.

    A perfect frame reports PSNR = `metrics.PSNR_CAP` (100 dB), full-frame and masked alike, never inf,
    so means stay finite; SSIM 1, LPIPS 0, depth MAE 0 and SROCC 1.

    Distributed `test`: each rank renders and saves its own frames; at the end the rows of all ranks are gathered,
    de-duplicated by frame index (the sampler pads by repeating frames) and only global rank 0 writes the CSV and JSON
    files and moves the folder into place.
    """

    def __init__(
        self,
        output_dir: str | None = None,
        lpips: bool = True,
        lpips_weights: str | None = None,
        visibility_masks: bool = True,
        min_views: int = MIN_VIEWS,
    ) -> None:
        """
        Args:
            output_dir: where test outputs go; default <trainer.default_root_dir>/test (predict: .../predict).
            lpips: compute LPIPS (AlexNet, v0.1). Needs the AlexNet trunk weights, see lpips_weights.
            lpips_weights: AlexNet trunk weights (torchvision .pth or the LPIPS .npz); None: the
                SIMPLENERF_LPIPS_WEIGHTS environment variable, then the torch hub cache, then a download.
            visibility_masks: also score each test frame over its visibility mask (masked_*), when the scene has
                reference depth.
            min_views: a test pixel is evaluated by the masked scores if at least this many train views see it.
        """
        self.output_dir, self.use_lpips, self.lpips_weights = output_dir, lpips, lpips_weights
        self.use_masks, self.min_views = visibility_masks, min_views
        self.lpips_net: LPIPS | None = None
        self.rows: list[dict] = []
        self.masks: dict[int, torch.Tensor] = {}
        self._final: Path | None = None
        self._partial: Path | None = None
        self._saved_config: Path | None = None
        self.run_config: str | None = None
        """YAML of the config this test runs with, set by the CLI (`cli.RunConfig`); saved beside the results."""

    def check_scoring(self, stage: str) -> None:
        """Loads LPIPS for `test`: missing weights stop the run before anything is rendered or written. `fit` checks
        them too (found, or downloaded into the torch hub cache, then let go): the run's config names this callback,
        and its `test` would otherwise stop at the missing weights only after the whole training. The CLI calls this
        only when the split has test frames: without them `test` renders instead of scoring (own photos)."""
        if stage == "test" and self.use_lpips and self.lpips_net is None:
            self.lpips_net = LPIPS.from_weights(self.lpips_weights, allow_download=True)
        elif stage == "fit" and self.use_lpips:
            try:
                LPIPS.from_weights(self.lpips_weights, allow_download=True)
            except LPIPSWeightsNotFound as e:
                raise LPIPSWeightsNotFound(f"the test of this run (--evaluation.lpips true) will need LPIPS weights, "
                                           f"checked before training: {e}") from None

    def final_folder(self, trainer: L.Trainer, stage: str) -> Path:
        return Path(self.output_dir or os.path.join(trainer.default_root_dir, stage))

    def check_outputs(self, trainer: L.Trainer, stage: str) -> None:
        """Before anything is rendered: earlier results in the output folder must be movable aside at the end (a
        rename there and back), or the render would be lost; RunFolderError naming the folder otherwise."""
        if stage not in ("test", "predict") or not trainer.is_global_zero:
            return
        final = self.final_folder(trainer, stage)
        if not final.exists():
            return
        probe = final.with_name(f".{final.name}.move-check-{os.getpid()}")
        try:
            final.rename(probe)
        except OSError as e:
            raise RunFolderError(
                f"the earlier results in {final} cannot be moved aside for the new ones ({e.strerror or e}); move "
                "them yourself, or choose another --evaluation.output_dir"
            ) from None
        probe.rename(final)

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        # A stopped test or predict (an error, a signal) leaves no partial results behind.
        if self._partial is not None and trainer.is_global_zero:
            shutil.rmtree(self._partial, ignore_errors=True)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage not in ("test", "predict"):
            return
        self.check_scoring(stage)  # loads LPIPS, if the CLI has not (a test run outside it)
        name = "test" if stage == "test" else "predict"
        self._final = self.final_folder(trainer, name)
        self._partial = self._final.with_name(self._final.name + ".partial")
        if trainer.is_global_zero:
            shutil.rmtree(self._partial, ignore_errors=True)
            for sub in ("rgb", "depth", *(("mask",) if stage == "test" else ())):
                (self._partial / sub).mkdir(parents=True)
        # Every rank writes its frames into the folder rank 0 just made.
        trainer.strategy.barrier("evaluator_setup")
        self.rows = []
        self.masks = {}
        if stage == "test":
            # LightningCLI saves the run's config as <trainer.log_dir>/config.yaml; log_dir must be read on all ranks.
            log_dir = trainer.log_dir
            self._saved_config = Path(log_dir) / "config.yaml" if log_dir is not None else None
            self.masks = self._visibility_masks(trainer)

    def _visibility_masks(self, trainer: L.Trainer) -> dict[int, torch.Tensor]:
        scene = _scene(trainer)
        if not self.use_masks or scene is None or scene.views.depths is None:
            return {}
        if len(scene.split.train) < self.min_views:
            print(f"visibility masks: {len(scene.split.train)} train views cannot reach min_views={self.min_views}; "
                  "masked scores are skipped", flush=True)
            return {}
        return scene_visibility_masks(scene.views, scene.split.train, scene.split.test, self.min_views,
                                      progress=trainer.is_global_zero)

    def _save_frame(self, name: str, pred: FrameRender) -> None:
        assert self._partial is not None
        depth = pred.depth.float().cpu().numpy()
        write_png(self._partial / "rgb" / f"{name}.png", pred.rgb.float().cpu().numpy())
        np.save(self._partial / "depth" / f"{name}.npy", depth)
        write_png(self._partial / "depth" / f"{name}.png", colorize_depth(depth))

    def on_test_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        target = batch.rgb.reshape(outputs.rgb.shape)
        gt_depth = batch.depth.reshape(outputs.depth.shape) if batch.depth is not None else None
        if self.lpips_net is not None:
            self.lpips_net.to(outputs.rgb.device)
        index = int(batch.index)
        mask = self.masks.get(index)
        scores = frame_scores(outputs.rgb, target, outputs.depth, gt_depth, self.lpips_net, mask)
        self.rows.append({"frame": batch.name, "index": index, **scores})
        for key, value in scores.items():
            if value is not None:
                pl_module.log(f"test/{key}", value, batch_size=1)
        self._save_frame(batch.name, outputs)
        if mask is not None:
            write_mask_png(self._partial / "mask" / f"{batch.name}.png", mask.cpu().numpy())

    def on_predict_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        self._save_frame(batch.name, outputs)

    def _commit_outputs(self, trainer: L.Trainer, extra: dict) -> None:
        assert self._partial is not None and self._final is not None
        if not trainer.is_global_zero:
            return
        with open(self._partial / "run.json", "w") as f:
            json.dump({"written": datetime.now(timezone.utc).isoformat(), "git_commit": git_commit(), **extra}, f,
                      indent=2)
        if self._final.exists():
            # Earlier results are kept, renamed after the time they were written.
            archive = archive_path(self._final)
            self._final.rename(archive)
            print(f"earlier results of {self._final} moved to {archive}", flush=True)
        self._partial.rename(self._final)

    def _provenance(self, trainer: L.Trainer) -> dict:
        """scene and n_views of the data module (None if it has none)."""
        scene = _scene(trainer)
        if scene is None:
            return {"scene": None, "n_views": None}
        return {"scene": scene.source.name, "n_views": len(scene.split.train)}

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        assert self._partial is not None and self._final is not None
        # Collective: also the point after which every rank has written its frames.
        rows = gather_rows(self.rows)
        if not trainer.is_global_zero:
            return
        with open(self._partial / "metrics.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["frame", "index", *ALL_METRICS])
            writer.writeheader()
            writer.writerows(rows)
        config = None
        if self.run_config is not None:
            (self._partial / "config.yaml").write_text(self.run_config)
            config = str(self._final / "config.yaml")
        elif self._saved_config is not None and self._saved_config.is_file():
            shutil.copyfile(self._saved_config, self._partial / "config.yaml")
            config = str(self._final / "config.yaml")
        means = summarize(rows)
        checkpoint = str(trainer.ckpt_path) if trainer.ckpt_path is not None else None
        summary = {**self._provenance(trainer), "frames": len(rows), **means, "checkpoint": checkpoint,
                   "git_commit": git_commit(), "config": config}
        with open(self._partial / "summary.json", "w") as f:
            json.dump(summary, f, indent=2)
        self._commit_outputs(trainer, {"checkpoint": checkpoint, "stage": "test"})
        print(f"test outputs: {self._final} (PSNR of a perfect frame: {PSNR_CAP:g})\n" + format_table(rows, means),
              flush=True)

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Every rank must have written its renders before rank 0 moves the folder.
        trainer.strategy.barrier("evaluator_predict_end")
        self._commit_outputs(trainer, {"checkpoint": trainer.ckpt_path, "stage": "predict"})
