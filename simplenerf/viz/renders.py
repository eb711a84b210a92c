"""Pictures of a validation render (RGB, depth, accumulation, error) and the callback that logs and saves them.

Images are 8-bit RGB numpy arrays [H, W, 3], what both W&B and `evaluation.write_png` take.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch

from simplenerf.evaluation.evaluator import colorize_depth, write_png
from simplenerf.evaluation.metrics import psnr

KINDS = ("rgb", "depth", "accumulation", "error")


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (clipped) to 8 bits, same shape."""
    return np.round(np.clip(image, 0.0, 1.0) * 255).astype(np.uint8)


def grey_picture(values: np.ndarray) -> np.ndarray:
    """[H, W] values in [0, 1] (e.g. accumulated opacity) as a grey RGB picture [H, W, 3]."""
    return np.repeat(to_uint8(values)[..., None], 3, axis=-1)


def error_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel |pred - target| averaged over channels: [H, W] from images [H, W, 3]."""
    assert pred.shape == target.shape and pred.shape[-1] == 3, f"images differ: {pred.shape} vs {target.shape}"
    return (pred - target.to(pred)).abs().mean(dim=-1)


def colorize_error(error: np.ndarray, max_error: float) -> np.ndarray:
    """An error map [H, W] as an RGB picture [H, W, 3]: inferno colours, 0 black, `max_error` and above brightest.

    The range is fixed rather than per frame so that pictures of different steps can be compared."""
    scaled = to_uint8(error / max_error)
    return cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_INFERNO), cv2.COLOR_BGR2RGB)


def render_pictures(pred: dict[str, torch.Tensor], target: torch.Tensor, max_error: float) -> dict[str, np.ndarray]:
    """The pictures of one rendered frame, by kind (`KINDS`).

    Args:
        pred: rgb [H, W, 3], depth [H, W], accumulation [H, W] (the module's `render_frame`).
        target: [H, W, 3] ground truth in [0, 1].
        max_error: error shown at the top of the error colour map.
    """
    as_numpy = {k: pred[k].detach().float().cpu().numpy() for k in ("rgb", "depth", "accumulation")}
    error = error_map(pred["rgb"].detach(), target).float().cpu().numpy()
    return {
        "rgb": to_uint8(as_numpy["rgb"]),
        "depth": colorize_depth(as_numpy["depth"]),  # the frame's own percentiles: contrast within one picture
        "accumulation": grey_picture(as_numpy["accumulation"]),
        "error": colorize_error(error, max_error),
    }


def publish_picture(trainer: L.Trainer, key: str, picture: np.ndarray, file_name: str, caption: str | None = None,
                    log: bool = True, save: bool = True) -> None:
    """Sends a picture [H, W, 3] to every logger that takes images (W&B: `key`, at the trainer's step) and, on global
    rank 0, writes it to `<trainer.default_root_dir>/val/<file_name>`."""
    if log:
        for logger in trainer.loggers:
            log_image = getattr(logger, "log_image", None)
            if log_image is not None:
                extra = {} if caption is None else {"caption": [caption]}
                log_image(key=key, images=[picture], step=trainer.global_step, **extra)
    if save and trainer.is_global_zero:
        out = Path(trainer.default_root_dir) / "val"
        out.mkdir(parents=True, exist_ok=True)
        write_png(out / file_name, picture)


class ValidationRenders(L.Callback):
    """Pictures of the validation frame at every validation: predicted RGB, colourised depth (inverse depth, near =
    warm), accumulation (grey) and |pred - gt| (with the frame's PSNR in the caption).

    Logged to every logger that has `log_image` (W&B: keys `val/render_<kind>`, slider over steps) and saved as
    `<trainer.default_root_dir>/val/step{global_step:06d}_<kind>.png`. Only the first validation frame is drawn;
    sanity-check runs are skipped.
    """

    def __init__(
        self, save_to_disk: bool = True, log_images: bool = True, every_n_validations: int = 1, max_error: float = 0.5
    ) -> None:
        """
        Args:
            save_to_disk: write the PNGs under <trainer.default_root_dir>/val/.
            log_images: send the pictures to loggers that take images (W&B).
            every_n_validations: draw at the 1st, (1+n)th, (1+2n)th ... validation.
            max_error: mean absolute RGB error drawn with the brightest colour of the error map.
        """
        if every_n_validations < 1:
            raise ValueError(f"every_n_validations must be at least 1, got {every_n_validations}")
        if max_error <= 0:
            raise ValueError(f"max_error must be positive, got {max_error}")
        self.save_to_disk, self.log_images = save_to_disk, log_images
        self.every_n_validations, self.max_error = every_n_validations, max_error
        self.validations = 0  # counted in this process (restarts at 0 when a run resumes)

    def on_validation_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self.validations += 1

    def on_validation_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        if trainer.sanity_checking or batch_idx != 0 or dataloader_idx != 0 or not isinstance(outputs, dict):
            return
        if (self.validations - 1) % self.every_n_validations != 0:
            return
        target = batch["rgb"].reshape(outputs["rgb"].shape)
        pictures = render_pictures(outputs, target, self.max_error)
        frame_psnr = float(psnr(outputs["rgb"][None].detach(), target[None])[0])
        step = trainer.global_step
        name = batch.get("name", "val")
        captions = {kind: f"{name} step {step}" for kind in KINDS}
        captions["error"] = f"{name} step {step} PSNR {frame_psnr:.2f} dB"
        for kind in KINDS:
            publish_picture(trainer, f"val/render_{kind}", pictures[kind], f"step{step:06d}_{kind}.png",
                            captions[kind], log=self.log_images, save=self.save_to_disk)
