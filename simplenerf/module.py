"""The LightningModule: composes the NeRF, its losses and the optimiser; nothing else lives here.

`training_step` mirrors the paper's total loss (Sec. 4.4), L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc,
with the terms that are configured; evaluation (metrics, files) is the `evaluation.Evaluator` callback's job.
"""

from __future__ import annotations

from typing import Literal

import lightning as L
import numpy as np
import torch
from torch import nn

from simplenerf.evaluation.metrics import psnr
from simplenerf.geometry.rays import RayBundle, make_rays, pixel_grid
from simplenerf.method.augmentations import Augmentation
from simplenerf.method.losses import color_loss, sparse_depth_loss
from simplenerf.method.reliability import MaskContext, ReliabilityMask, mask_fractions, masked_depth_loss, nearest_views
from simplenerf.model.nerf import NeRF
from simplenerf.viz.renders import publish_picture


class SimpleNeRF(L.LightningModule):
    """SimpleNeRF: the main coarse/fine NeRF and its training losses."""

    def __init__(
        self,
        nerf: NeRF,
        augmentations: list[Augmentation] | None = None,
        coarse_fine_mask: ReliabilityMask | None = None,
        supervision: Literal["bidirectional", "one_way"] = "one_way",
        color_weight: float = 1.0,
        sparse_depth_weight: float = 0.1,
        coarse_fine_weight: float = 0.1,
        coarse_fine_on_sparse_rays: bool = False,
        lr: float = 5e-4,
        lr_decay_rate: float = 0.1,
        lr_decay_steps: int = 250000,
        chunk: int = 8192,
    ) -> None:
        """
        Args:
            nerf: the main model (coarse and fine fields, sampling, rendering).
            augmentations: simplified fields trained beside the main model (points and views in the paper); each
                adds its colour and sparse-depth losses and a masked depth loss `loss_weights[name]` with the main
                model. Empty: no augmentation (DS-NeRF when sparse depth is on).
            coarse_fine_mask: reliability mask of the coarse-fine consistency loss L_cfc; None disables L_cfc.
            supervision: `bidirectional`: where the mask is -1 the other depth is trained toward the main one (the
                paper's equations); `one_way`: only mask +1 rays train the main depth (what the release trains; the
                default: on the CPU benchmark of the README it was slightly better in colour, within noise in depth).
            color_weight: lambda_1, weight of the colour loss.
            sparse_depth_weight: lambda_2, weight of DS-NeRF's sparse-depth loss (used when the data module serves
                sparse-depth rays, `sparse_rays_per_batch` > 0).
            coarse_fine_weight: lambda_5, weight of L_cfc (a warm-up schedule may override it per step).
            coarse_fine_on_sparse_rays: the release also adds an unmasked (z_coarse - sg(z_fine))^2 on the
                sparse-depth rays to L_cfc.
            lr: initial Adam learning rate.
            lr_decay_rate: the learning rate is lr * lr_decay_rate ** (step / lr_decay_steps). The authors' release
                uses 0.1 over 250000 steps (ends near 2e-4 at 100k; the published scores); the paper's text,
                "decay to 5e-6", is 0.01 over 100000 steps.
            lr_decay_steps: see lr_decay_rate.
            chunk: rays per forward pass when rendering full frames (bounds memory, not results).
        """
        super().__init__()
        self.save_hyperparameters(ignore=["nerf", "augmentations", "coarse_fine_mask"])
        self.nerf = nerf
        self.augmentations = nn.ModuleList(augmentations or [])
        self.coarse_fine_mask = coarse_fine_mask
        names = [aug.name for aug in self.augmentations]
        if len(set(names)) != len(names) or {"color", "sparse_depth", "cfc"} & set(names):
            raise ValueError(f"augmentation names must be unique and not color/sparse_depth/cfc, got {names}")
        # lambda_1 .. lambda_5 by loss name; `callbacks.LossWeightSchedule` changes them per step (the warm-up).
        self.loss_weights = {"color": color_weight, "sparse_depth": sparse_depth_weight, "cfc": coarse_fine_weight}
        self.loss_weights.update({aug.name: aug.depth_weight for aug in self.augmentations})
        self.train_views: tuple[torch.Tensor, ...] | None = None  # images, intrinsics, c2w, nearest (for masks)

    def on_fit_start(self) -> None:
        if self.augmentations or self.coarse_fine_mask is not None:
            views = self.trainer.datamodule.train_views
            self.train_views = tuple(t.to(self.device) for t in (views.images, views.intrinsics, views.c2w))
            self.train_views += (nearest_views(self.train_views[2]),)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        rays = RayBundle.from_batch(batch)
        n = len(rays)  # random rays first, then the sparse-depth rays, all rendered in one pass
        has_sparse = "sparse_depth" in batch
        if has_sparse:
            rays = rays.cat(RayBundle.from_batch(batch, prefix="sparse_"))
        main = self.nerf(rays, randomized=True)
        augmented = [aug.render(self.nerf, main, randomized=True) for aug in self.augmentations]

        # L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc (paper Sec. 4.4)
        renders = [main.coarse, main.fine, *augmented]
        losses = {"color": color_loss([r[:n] for r in renders], batch["rgb"])}
        if has_sparse:  # not on the main coarse depth
            sparse = [r[n:] for r in renders[1:]]
            losses["sparse_depth"] = sparse_depth_loss(sparse, batch["sparse_depth"], batch["sparse_weight"])
        for name, mask, tied, other in self.depth_pairs(main, augmented):
            if self.loss_weights[name] > 0:  # free before the warm-up ends
                losses[name] = self.depth_supervision(name, mask, batch, tied[:n], other[:n])
        if "cfc" in losses and has_sparse and self.hparams.coarse_fine_on_sparse_rays:
            losses["cfc"] = losses["cfc"] + torch.mean((main.coarse.depth[n:] - main.fine.depth[n:].detach()) ** 2)
        loss = sum(self.loss_weights[name] * value for name, value in losses.items())

        # sync_dist: under DDP every rank trains on its own rays; the logged values are their mean (no-op otherwise).
        self.log_dict({f"train/loss_{name}": value for name, value in losses.items()}, sync_dist=True)
        self.log_dict({"train/loss": loss, "train/psnr_fine": psnr_of_mse(main.fine[:n].rgb, batch["rgb"])},
                      sync_dist=True)
        self.log("loss", loss, prog_bar=True, logger=False)
        return loss

    def depth_pairs(self, main, augmented: list) -> list[tuple[str, ReliabilityMask, object, object]]:
        """(loss name, mask, main render, other render) of every masked depth loss: L_ap, L_av, ..., then L_cfc."""
        pairs = [(aug.name, aug.mask, aug.main_output(main), out)
                 for aug, out in zip(self.augmentations, augmented, strict=True)]
        if self.coarse_fine_mask is not None:
            pairs.append(("cfc", self.coarse_fine_mask, main.coarse, main.fine))
        return pairs

    def depth_supervision(self, name: str, mask: ReliabilityMask, batch: dict, main, other) -> torch.Tensor:
        """The masked depth loss between a main render and another one (augmentation, or fine for L_cfc)."""
        assert self.train_views is not None, "on_fit_start did not run"
        context = MaskContext.from_batch(*self.train_views, batch)
        m = mask(context, main.depth.detach(), other.depth.detach())
        if m is not None:
            self.log_dict({f"train/mask_{name}/{k}": v for k, v in mask_fractions(m).items()}, sync_dist=True)
        return masked_depth_loss(main.depth, other.depth, m, self.hparams.supervision)

    def render_frame(self, batch: dict) -> dict[str, torch.Tensor]:
        """Deterministic full-frame render: rgb [H, W, 3], depth [H, W], accumulation [H, W], coarse_depth [H, W]."""
        h, w = int(batch["height"]), int(batch["width"])
        out = self.nerf.render_rays_chunked(RayBundle.from_batch(batch), self.hparams.chunk)
        return {k: v.reshape(h, w, *v.shape[1:]) for k, v in out.items()}

    def validation_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        pred = self.render_frame(batch)
        target = batch["rgb"].reshape(pred["rgb"].shape)
        self.log("val/psnr", psnr(pred["rgb"][None], target[None])[0], prog_bar=True, batch_size=1, sync_dist=True)
        return pred

    def on_validation_epoch_end(self) -> None:
        """Logs the reliability masks on the first train view: fractions of +1/-1/0 and an image per mask."""
        if self.train_views is None or self.trainer.sanity_checking:
            return
        for name, m in self.reliability_maps(view=0).items():
            self.log_dict({f"val/mask_{name}/{k}": v for k, v in mask_fractions(m).items()}, sync_dist=True)
            if not self.trainer.is_global_zero:  # every rank computed the same maps; one writes them
                continue
            file_name = f"mask_{name}_step{self.global_step:06d}.png"
            publish_picture(self.trainer, f"val/mask_{name}", mask_picture(m), file_name)

    @torch.no_grad()
    def reliability_maps(self, view: int) -> dict[str, torch.Tensor]:
        """Masks [H, W] in {-1, 0, +1} of each augmentation and of L_cfc on train view `view`, at every pixel."""
        assert self.train_views is not None, "on_fit_start did not run"
        images, intrinsics, c2w, _ = self.train_views
        h, w = images.shape[1:3]
        uv = pixel_grid(h, w, self.device)
        views = torch.full((h * w,), view, device=self.device)
        maps: dict[str, list[torch.Tensor]] = {}
        for start in range(0, h * w, self.hparams.chunk):
            part = make_rays(intrinsics[view : view + 1], c2w[view : view + 1], uv[start : start + self.hparams.chunk],
                             w, h, self.nerf.near)
            part.update(view=views[start : start + self.hparams.chunk], uv=uv[start : start + self.hparams.chunk])
            main = self.nerf(RayBundle.from_batch(part), randomized=False)
            context = MaskContext.from_batch(*self.train_views, part)
            augmented = [aug.render(self.nerf, main, False) for aug in self.augmentations]
            for name, mask, main_out, other in self.depth_pairs(main, augmented):
                m = mask(context, main_out.depth, other.depth)
                if m is not None:
                    maps.setdefault(name, []).append(m)
        return {name: torch.cat(parts).reshape(h, w) for name, parts in maps.items()}

    def test_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def predict_step(self, batch: dict, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def configure_optimizers(self):
        optimizer = torch.optim.Adam(self.parameters(), lr=self.hparams.lr, betas=(0.9, 0.999))
        rate, steps = self.hparams.lr_decay_rate, self.hparams.lr_decay_steps
        schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: rate ** (step / steps))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}


def mask_picture(mask: torch.Tensor) -> np.ndarray:
    """8-bit RGB picture of a ternary mask as in the paper's supplement: black where the other (augmented or fine)
    depth is preferred (+1), white where the main depth is (-1), grey where neither is reliable (0)."""
    grey = (127.5 * (1.0 - mask.float())).round().clamp(0, 255).to(torch.uint8).cpu().numpy()
    return np.repeat(grey[..., None], 3, axis=-1)


@torch.no_grad()
def psnr_of_mse(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Training PSNR (float, not 8-bit: a progress signal, not an evaluation metric)."""
    return -10.0 * torch.log10(torch.mean((rgb - target) ** 2))
