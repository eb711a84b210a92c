"""The LightningModule: composes the NeRF, its losses and the optimiser; nothing else lives here.

`training_step` mirrors the paper's total loss (Sec. 4.4), L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc,
with the terms that are configured; evaluation (metrics, files) is the `evaluation.Evaluator` callback's job.
"""

from __future__ import annotations

import lightning as L
import torch

from simplenerf.losses import color_loss
from simplenerf.metrics import psnr
from simplenerf.nerf import NeRF
from simplenerf.rays import RayBundle


class SimpleNeRF(L.LightningModule):
    """SimpleNeRF: the main coarse/fine NeRF and its training losses."""

    def __init__(
        self,
        nerf: NeRF,
        color_weight: float = 1.0,
        lr: float = 5e-4,
        lr_decay_rate: float = 0.1,
        lr_decay_steps: int = 250000,
        chunk: int = 8192,
    ) -> None:
        """
        Args:
            nerf: the main model (coarse and fine fields, sampling, rendering).
            color_weight: lambda_1, weight of the colour loss.
            lr: initial Adam learning rate.
            lr_decay_rate: the learning rate is lr * lr_decay_rate ** (step / lr_decay_steps). The authors' release
                uses 0.1 over 250000 steps (ends near 2e-4 at 100k; the published scores); the paper's text,
                "decay to 5e-6", is 0.01 over 100000 steps.
            lr_decay_steps: see lr_decay_rate.
            chunk: rays per forward pass when rendering full frames (bounds memory, not results).
        """
        super().__init__()
        self.save_hyperparameters(ignore=["nerf"])
        self.nerf = nerf

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        rays = RayBundle.from_batch(batch)
        out = self.nerf(rays, randomized=True)
        loss_color = color_loss([out.coarse, out.fine], batch["rgb"])
        loss = self.hparams.color_weight * loss_color
        self.log_dict(
            {"train/loss": loss, "train/loss_color": loss_color, "train/psnr_fine": psnr_of_mse(out, batch)},
            prog_bar=False,
        )
        self.log("loss", loss, prog_bar=True, logger=False)
        return loss

    def render_frame(self, batch: dict) -> dict[str, torch.Tensor]:
        """Deterministic full-frame render: rgb [H, W, 3], depth [H, W], accumulation [H, W], coarse_depth [H, W]."""
        h, w = int(batch["height"]), int(batch["width"])
        out = self.nerf.render_rays_chunked(RayBundle.from_batch(batch), self.hparams.chunk)
        return {k: v.reshape(h, w, *v.shape[1:]) for k, v in out.items()}

    def validation_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        pred = self.render_frame(batch)
        target = batch["rgb"].reshape(pred["rgb"].shape)
        self.log("val/psnr", psnr(pred["rgb"][None], target[None])[0], prog_bar=True, batch_size=1)
        return pred

    def test_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def predict_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def configure_optimizers(self):
        optimizer = torch.optim.Adam(self.parameters(), lr=self.hparams.lr, betas=(0.9, 0.999))
        rate, steps = self.hparams.lr_decay_rate, self.hparams.lr_decay_steps
        schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: rate ** (step / steps))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}


@torch.no_grad()
def psnr_of_mse(out, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Training PSNR of the fine colour (float, not 8-bit: a progress signal, not an evaluation metric)."""
    return -10.0 * torch.log10(torch.mean((out.fine.rgb - batch["rgb"]) ** 2))
