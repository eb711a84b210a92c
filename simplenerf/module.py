"""The LightningModule: composes the NeRF, its losses and the optimiser; nothing else lives here.

`training_step` mirrors the paper's total loss (Sec. 4.4), L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc,
with the terms that are configured; evaluation (metrics, files) is the `evaluation.Evaluator` callback's job.
"""

from __future__ import annotations

import lightning as L
import torch

from simplenerf.losses import color_loss, sparse_depth_loss
from simplenerf.metrics import psnr
from simplenerf.nerf import NeRF
from simplenerf.rays import RayBundle


class SimpleNeRF(L.LightningModule):
    """SimpleNeRF: the main coarse/fine NeRF and its training losses."""

    def __init__(
        self,
        nerf: NeRF,
        color_weight: float = 1.0,
        sparse_depth_weight: float = 0.1,
        lr: float = 5e-4,
        lr_decay_rate: float = 0.1,
        lr_decay_steps: int = 250000,
        chunk: int = 8192,
    ) -> None:
        """
        Args:
            nerf: the main model (coarse and fine fields, sampling, rendering).
            color_weight: lambda_1, weight of the colour loss.
            sparse_depth_weight: lambda_2, weight of DS-NeRF's sparse-depth loss (used when the data module serves
                sparse-depth rays, `sparse_rays_per_batch` > 0).
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

        self.loss_weights = {"color": color_weight, "sparse_depth": sparse_depth_weight}

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        rays = RayBundle.from_batch(batch)
        n = len(rays)  # random rays first, then the sparse-depth rays, rendered in one pass
        has_sparse = "sparse_depth" in batch
        if has_sparse:
            rays = rays.cat(RayBundle.from_batch(batch, prefix="sparse_"))
        out = self.nerf(rays, randomized=True)

        losses = {"color": color_loss([out.coarse[:n], out.fine[:n]], batch["rgb"])}
        if has_sparse:
            losses["sparse_depth"] = sparse_depth_loss([out.fine[n:]], batch["sparse_depth"], batch["sparse_weight"])
        loss = sum(self.loss_weights[name] * value for name, value in losses.items())

        self.log_dict({f"train/loss_{name}": value for name, value in losses.items()})
        self.log_dict({"train/loss": loss, "train/psnr_fine": psnr_of_mse(out.fine[:n].rgb, batch["rgb"])})
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
def psnr_of_mse(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Training PSNR (float, not 8-bit: a progress signal, not an evaluation metric)."""
    return -10.0 * torch.log10(torch.mean((rgb - target) ** 2))
