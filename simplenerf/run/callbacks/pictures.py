"""What a run draws while it trains: the validation frame's pictures and reliability masks at every validation
(`ValidationRenders`), the video along the scene's camera path at the end of `fit` (`TrainingVideo`). The drawing
itself is `simplenerf.viz`'s."""

from __future__ import annotations

from pathlib import Path

import lightning as L
from jsonargparse.typing import NonNegativeInt, PositiveFloat, PositiveInt

from simplenerf.geometry.trajectories import TrajectoryKind
from simplenerf.method.module import SimpleNeRF
from simplenerf.method.reliability import mask_fractions
from simplenerf.metrics.scores import psnr
from simplenerf.model.nerf import FrameRender
from simplenerf.viz.pictures import mask_picture, publish_picture
from simplenerf.viz.renders import KINDS, render_pictures
from simplenerf.viz.video import render_scene_video


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


class TrainingVideo(L.Callback):
    """At the end of `fit`, the video of the trained model ([RGB | depth] along the scene's camera path, as
    `simplenerf render-video`) in `<trainer.default_root_dir>/video_<path>.mp4`, logged to every logger that takes
    videos (W&B: the media panel `video/<path>`). Rendered by global rank 0; off unless `frames` > 0."""

    def __init__(self, frames: NonNegativeInt = 0, rotations: float = 2, scale: PositiveFloat = 1.0,
                 fps: float = 30, trajectory: TrajectoryKind | None = None) -> None:
        """
        Args:
            frames: frames of the spiral (the recorded path has its own); 0: no video.
            rotations: turns of the spiral.
            scale: render at this times the data's resolution (0.25: a quarter; a full-resolution video on a CPU
                takes long).
            fps: frames per second.
            trajectory: spiral or recorded; null: the scene's `camera_path` (RealEstate: recorded, else spiral).
        """
        self.frames, self.rotations, self.scale, self.fps = frames, rotations, scale, fps
        self.trajectory = trajectory

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.frames <= 0 or not trainer.is_global_zero:
            return
        kind = self.trajectory or trainer.datamodule.scene.camera_path
        out = Path(trainer.default_root_dir) / f"video_{kind}.mp4"
        written, n, width, height, kind, _ = render_scene_video(
            pl_module, trainer.datamodule, out, kind, self.frames, self.rotations, self.scale, self.fps
        )
        for logger in trainer.loggers:
            log_video = getattr(logger, "log_video", None)
            if log_video is not None:
                log_video(key=f"video/{kind}", videos=[str(written)], step=trainer.global_step, format=["mp4"])
        print(f"video: {written} ({n} frames of {2 * width}x{height}, {kind})", flush=True)
