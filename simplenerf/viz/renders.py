"""The validation pictures and the callback that logs and saves them: RGB, depth, accumulation and error of the
validation view, and SimpleNeRF's reliability masks on the first train view.
"""

from __future__ import annotations

import lightning as L
import numpy as np
import torch
from jsonargparse.typing import PositiveInt

from simplenerf.method.reliability import mask_fractions
from simplenerf.metrics.scores import psnr
from simplenerf.model.nerf import FrameRender
from simplenerf.module import SimpleNeRF
from simplenerf.viz.pictures import (
    colorize_depth,
    colorize_error,
    grey_picture,
    mask_picture,
    publish_picture,
    to_uint8,
)

KINDS = ("rgb", "depth", "accumulation", "error")


def error_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel |pred - target| averaged over channels: [H, W] from images [H, W, 3]."""
    assert pred.shape == target.shape and pred.shape[-1] == 3, f"images differ: {pred.shape} vs {target.shape}"
    return (pred - target.to(pred)).abs().mean(dim=-1)


def render_pictures(pred: FrameRender, target: torch.Tensor, max_error: float) -> dict[str, np.ndarray]:
    """The pictures of one rendered frame, by kind (`KINDS`).

    Args:
        pred: rgb [H, W, 3], depth [H, W], accumulation [H, W] (the module's `render_frame`).
        target: [H, W, 3] ground truth in [0, 1].
        max_error: error shown at the top of the error colour map.
    """
    as_numpy = {k: x.detach().float().cpu().numpy() for k, x in (("rgb", pred.rgb), ("depth", pred.depth),
                                                                   ("accumulation", pred.accumulation))}
    error = error_map(pred.rgb.detach(), target).float().cpu().numpy()
    return {
        "rgb": to_uint8(as_numpy["rgb"]),
        "depth": colorize_depth(as_numpy["depth"]),  # the frame's own percentiles: contrast within one picture
        "accumulation": grey_picture(as_numpy["accumulation"]),
        "error": colorize_error(error, max_error),
    }


class ValidationRenders(L.Callback):
    """Pictures of the validation frame at every validation: predicted RGB, colourised depth (inverse depth, near =
    warm), accumulation (grey) and |pred - gt| (with the frame's PSNR in the caption).

    Logged to every logger that has `log_image` (W&B: keys `val/render_<kind>`, slider over steps) and saved as
    `<trainer.default_root_dir>/val/step{global_step:06d}_<kind>.png`. Only the first validation frame is drawn;
    sanity-check runs are skipped. At every validation it also logs SimpleNeRF's reliability masks on the first train
    view (`val/mask_<name>/{plus,minus,zero}` and a picture `val/mask_<name>`, saved as `mask_<name>_stepNNNNNN.png`;
    black: the other depth is preferred, white: the main one, grey: neither).
    """

    def __init__(
        self, save_to_disk: bool = True, log_images: bool = True, every_n_validations: PositiveInt = 1,
        max_error: float = 0.5,
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
        if trainer.sanity_checking or batch_idx != 0 or dataloader_idx != 0 or not isinstance(outputs, FrameRender):
            return
        if (self.validations - 1) % self.every_n_validations != 0:
            return
        target = batch.rgb.reshape(outputs.rgb.shape)
        pictures = render_pictures(outputs, target, self.max_error)
        frame_psnr = float(psnr(outputs.rgb[None].detach(), target[None])[0])
        step = trainer.global_step
        name = batch.name
        captions = {kind: f"{name} step {step}" for kind in KINDS}
        captions["error"] = f"{name} step {step} PSNR {frame_psnr:.2f} dB"
        for kind in KINDS:
            publish_picture(trainer, f"val/render_{kind}", pictures[kind], f"step{step:06d}_{kind}.png",
                            captions[kind], log=self.log_images, save=self.save_to_disk)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: SimpleNeRF) -> None:
        """The reliability masks on the first train view: fractions of +1 / -1 / 0 and a picture per mask."""
        if trainer.sanity_checking or pl_module.train_views is None:
            return
        for name, m in pl_module.reliability_maps(view=0).items():
            pl_module.log_dict({f"val/mask_{name}/{k}": v for k, v in mask_fractions(m).items()}, sync_dist=True)
            if trainer.is_global_zero:  # every rank computed the same maps; one writes them
                file_name = f"mask_{name}_step{trainer.global_step:06d}.png"
                publish_picture(trainer, f"val/mask_{name}", mask_picture(m), file_name, log=self.log_images,
                                save=self.save_to_disk)
