"""The LightningModule: composes the NeRF, its augmentations and the losses; nothing else lives here.

`training_step` mirrors the paper's total loss (Sec. 4.4), L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc, with
the terms that are configured. Pictures are the callbacks' job (`simplenerf.viz.renders`), evaluation (metrics,
files) the `Evaluator`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import lightning as L
import torch
from jsonargparse.typing import PositiveInt
from lightning.pytorch.cli import LRSchedulerCallable, OptimizerCallable
from torch import nn

from simplenerf.data.batches import Frame, RayBatch, SparseDepthBatch, TrainingBatch
from simplenerf.errors import SimpleNeRFError
from simplenerf.evaluation.metrics import psnr
from simplenerf.geometry.rays import pixel_grid
from simplenerf.geometry.views import Views
from simplenerf.method.augmentations import Augmentation
from simplenerf.method.losses import (
    coarse_fine_sparse_loss,
    color_loss,
    mass_concentration_loss,
    psnr_of_mse,
    sparse_depth_loss,
)
from simplenerf.method.reliability import ReliabilityMask, mask_fractions, masked_depth_loss
from simplenerf.model.nerf import NeRF, NeRFOutputs
from simplenerf.model.rendering import RenderOutputs
from simplenerf.optim import ExponentialDecay, default_optimizer, parameter_groups

RESERVED_LOSS_NAMES = ("color", "sparse_depth", "cfc", "regularization")


@dataclass
class Renders:
    """Every render of a batch of rays: the main coarse and fine NeRF and each augmentation, by name."""

    main: NeRFOutputs
    augmented: dict[str, RenderOutputs]

    def split(self, n: int) -> tuple[Renders, Renders]:
        """The renders of the first n rays (a training batch's random rays) and of the rest (its sparse rays)."""
        (first, rest), augmented = self.main.split(n), self.augmented.items()
        return Renders(first, {k: r[:n] for k, r in augmented}), Renders(rest, {k: r[n:] for k, r in augmented})


def ray_slices(n: int, size: int | None) -> list[slice]:
    """Consecutive slices of at most `size` (None: all n) of n rays."""
    size = size or n
    return [slice(start, min(start + size, n)) for start in range(0, n, size)]


def add_terms(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Two dicts of loss terms summed by name (L_cfc, for one, has a part on each kind of ray)."""
    return {**a, **{name: a[name] + value if name in a else value for name, value in b.items()}}


@dataclass
class DepthPair:
    """One masked depth loss: the main render tied to another one (an augmentation's, or fine for L_cfc)."""

    name: str
    mask: ReliabilityMask
    main: RenderOutputs
    other: RenderOutputs


class SimpleNeRF(L.LightningModule):
    """SimpleNeRF: the main coarse/fine NeRF and its training losses."""

    def __init__(
        self,
        nerf: NeRF,
        augmentations: list[Augmentation] | None = None,
        coarse_fine_mask: ReliabilityMask | None = None,
        supervision: Literal["bidirectional", "one_way"] = "one_way",
        depth_loss_space: Literal["metric", "inverse"] = "metric",
        color_weight: float = 1.0,
        sparse_depth_weight: float = 0.1,
        coarse_fine_weight: float = 0.1,
        coarse_fine_on_sparse_rays: bool = True,
        optimizer: OptimizerCallable | None = None,
        lr_scheduler: LRSchedulerCallable | None = None,
        group_lr: dict[str, float] | None = None,
        chunk: PositiveInt = 8192,
        backward_per_part: bool = False,
        rays_per_backward: PositiveInt | None = None,
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
            depth_loss_space: what L_ap, L_av and L_cfc compare: `metric` depth (the paper and the release) or
                `inverse` depth 1 / z, bounded by 1 / near (= 1 - NDC t with near 1). Metric depth grows without
                bound towards the NDC far plane, where a few rays can dominate these squared losses (on the
                RealEstate-10K grid runs, docs/results.md "Grid backbone"). The masks always compare metric depths.
            color_weight: lambda_1, weight of the colour loss.
            sparse_depth_weight: lambda_2, weight of DS-NeRF's sparse-depth loss (used when the data module serves
                sparse-depth rays, `sparse_rays_per_batch` > 0).
            coarse_fine_weight: lambda_5, weight of L_cfc (a warm-up schedule may override it per step).
            coarse_fine_on_sparse_rays: as the release, L_cfc also has an unmasked (z_coarse - sg(z_fine))^2 on the
                sparse-depth rays: the only path by which SfM depth reaches the main coarse field.
            optimizer: the optimiser, given the parameter groups; null: Adam(lr 5e-4, betas 0.9 / 0.999), the
                release's.
            lr_scheduler: the learning-rate schedule, stepped every iteration; null: `ExponentialDecay(0.1, 250000)`,
                the release's (lr * 0.1^(step / 250000)).
            group_lr: learning rates of named parameter groups (a field's `parameter_groups()`, e.g. a grid's
                "grid" and "decoder"); the other groups take the optimiser's.
            chunk: rays per forward pass when rendering full frames (bounds memory, not results).
            backward_per_part: render and backpropagate the random rays, then the sparse-depth rays (as the release's
                2048-ray sub-batches): the same loss and gradient with about half the activation memory (the random
                draws of jitter and noise differ from one pass). Not with DDP or fp16 loss scaling.
            rays_per_backward: with `backward_per_part`, at most this many rays per render-and-backward pass (the
                random rays and the sparse-depth rays each split into parts): the same loss and gradient, activation
                memory in proportion to the part. None: one part each. Set without `backward_per_part`: an error.
        """
        super().__init__()
        self.save_hyperparameters(ignore=["nerf", "augmentations", "coarse_fine_mask", "optimizer", "lr_scheduler"])
        self.nerf = nerf
        self.augmentations = nn.ModuleList(augmentations or [])
        self.coarse_fine_mask = coarse_fine_mask
        self.optimizer, self.lr_scheduler, self.group_lr = optimizer, lr_scheduler, dict(group_lr or {})
        if rays_per_backward is not None and (not backward_per_part or rays_per_backward < 1):
            raise SimpleNeRFError(f"model.rays_per_backward {rays_per_backward} needs model.backward_per_part true and "
                                  "a positive number of rays (it splits the per-part backward passes)")
        names = [aug.name for aug in self.augmentations]
        if len(set(names)) != len(names) or set(RESERVED_LOSS_NAMES) & set(names):
            raise ValueError(f"augmentation names must be unique and not one of {RESERVED_LOSS_NAMES}, got {names}")
        # lambda_1 .. lambda_5 by loss name; `callbacks.LossWeightSchedule` changes them per step (the warm-up).
        self.loss_weights = {"color": color_weight, "sparse_depth": sparse_depth_weight, "cfc": coarse_fine_weight}
        self.loss_weights.update({aug.name: aug.depth_weight for aug in self.augmentations})
        self.loss_weights.update({aug.concentration_name: aug.concentration_weight for aug in self.augmentations
                                  if aug.concentration_weight is not None})  # Simple-RF's, on the random rays
        self.train_views: Views | None = None  # what the reliability masks look at, on the module's device

    @property
    def needs_masks(self) -> bool:
        """Whether training compares depths across train views (needs at least 2 train views)."""
        return bool(self.augmentations) or self.coarse_fine_mask is not None

    def on_fit_start(self) -> None:
        if self.hparams.backward_per_part and getattr(self.trainer, "world_size", 1) > 1:
            raise SimpleNeRFError("backward_per_part runs two backward passes per step, which DDP's gradient "
                                  "synchronisation does not allow: set --model.backward_per_part false "
                                  "--model.rays_per_backward null with DDP")
        if self.needs_masks:
            self.train_views = self.trainer.datamodule.train_views.to(self.device)

    def render(self, rays, randomized: bool, color: bool = True) -> Renders:
        """The main NeRF and every augmentation along `rays` (a `RayBundle`); `color` False: depths only (the
        augmentations are evaluated at the main model's samples, which carry the flag)."""
        main = self.nerf(rays, randomized=randomized, color=color)
        return Renders(main, {aug.name: aug.render(self.nerf, main, randomized) for aug in self.augmentations})

    def training_step(self, batch: TrainingBatch, batch_idx: int) -> torch.Tensor:
        # L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc (paper Sec. 4.4): the colour and masked depth terms are
        # on the random rays, the sparse-depth terms on the sparse-depth rays.
        if self.hparams.backward_per_part and batch.sparse is not None:
            loss, losses, masks, fine_rgb = self.backward_in_parts(batch)
        else:  # one pass over the random rays followed by the sparse-depth rays, then split
            random, sparse = self.render(batch.rays, randomized=True).split(len(batch.random))
            losses, masks = self.random_ray_losses(random, batch.random)
            sparse_losses = self.sparse_ray_losses(sparse, batch.sparse)
            loss = self.weighted(losses) + self.weighted(sparse_losses, regularize=True)
            losses, fine_rgb = add_terms(losses, sparse_losses), random.main.fine.rgb

        # sync_dist: under DDP every rank trains on its own rays; the logged values are their mean (no-op otherwise).
        self.log_dict({f"train/loss_{name}": value for name, value in losses.items()}, sync_dist=True)
        self.log_dict({f"train/mask_{name}": value for name, value in masks.items()}, sync_dist=True)
        train_psnr = psnr_of_mse(fine_rgb, batch.random.rgb)
        self.log_dict({"train/loss": loss, "train/psnr_fine": train_psnr}, sync_dist=True)
        self.log("loss", loss, prog_bar=True, logger=False)
        return loss

    def backward_in_parts(self, batch: TrainingBatch):
        """Render and backpropagate the random rays, then the sparse-depth rays, in parts of at most
        `rays_per_backward` rays (the sparse rays depth only: no loss reads their colours, so the fields skip their
        colour branches). Every term is a mean over rays, so the parts' terms, each weighted by its share of the
        rays, sum to the one-pass terms, and their gradients to its gradient.

        Returns:
            (the total loss, whose graph is the last part's: Lightning backpropagates it; the earlier parts are
            already backpropagated), the terms by name, the mask fractions by name, [R, 3] main fine colours of the
            random rays (detached).
        """
        parts = [(batch.random[s], True) for s in ray_slices(len(batch.random), self.hparams.rays_per_backward)]
        parts += [(batch.sparse[s], False) for s in ray_slices(len(batch.sparse), self.hparams.rays_per_backward)]
        total, terms, masks, fine_rgb = torch.zeros((), device=self.device), {}, {}, []
        for i, (rays, is_random) in enumerate(parts):
            share = len(rays) / len(batch.random if is_random else batch.sparse)
            renders = self.render(rays.rays, randomized=True, color=is_random)
            if is_random:
                losses, part_masks = self.random_ray_losses(renders, rays)
                masks = add_terms(masks, {k: share * v for k, v in part_masks.items()})
                fine_rgb.append(renders.main.fine.rgb.detach())
            else:
                losses = self.sparse_ray_losses(renders, rays)
            losses = {name: share * value for name, value in losses.items()}
            last = i == len(parts) - 1
            loss = self.weighted(losses, regularize=last)  # the fields' regularisers once, with the last part
            if not last:
                loss.backward()  # frees this part's activations before the next part is rendered
                loss = loss.detach()
            total, terms = total + loss, add_terms(terms, {k: v.detach() for k, v in losses.items()})
        return total, terms, masks, torch.cat(fine_rgb)

    def random_ray_losses(
        self, renders: Renders, rays: RayBatch
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """Lcolor on main coarse, main fine and each augmentation; L_ap, L_av, L_cfc with their reliability masks
        (free, not even the mask, while a term's weight is 0: the warm-up). Also returns the masks' fractions of
        +1 / -1 / 0 rays, by "<loss name>/<plus|minus|zero>"."""
        augmented = list(renders.augmented.values())
        losses = {"color": color_loss([renders.main.coarse, renders.main.fine, *augmented], rays.rgb)}
        for aug in self.augmentations:  # Simple-RF's mass concentration (free while its weight is 0)
            if self.loss_weights.get(aug.concentration_name, 0.0) > 0:
                weights = renders.augmented[aug.name].weights
                losses[aug.concentration_name] = mass_concentration_loss(weights, aug.concentration_bins)
        masks = {}
        for pair in self.depth_pairs(renders):
            if self.loss_weights[pair.name] > 0:
                losses[pair.name], fractions = self.masked_depth_loss(pair, rays)
                masks.update({f"{pair.name}/{k}": v for k, v in fractions.items()})
        return losses, masks

    def sparse_ray_losses(self, renders: Renders, rays: SparseDepthBatch | None) -> dict[str, torch.Tensor]:
        """Lsd on main fine and each augmentation (not main coarse), and the release's unmasked part of L_cfc."""
        if rays is None:
            return {}
        fine_and_augmented = [renders.main.fine, *renders.augmented.values()]
        losses = {"sparse_depth": sparse_depth_loss(fine_and_augmented, rays.depth, rays.weight)}
        cfc_on = self.coarse_fine_mask is not None and self.loss_weights["cfc"] > 0
        if cfc_on and self.hparams.coarse_fine_on_sparse_rays:
            losses["cfc"] = coarse_fine_sparse_loss(renders.main.coarse, renders.main.fine)
        return losses

    def weighted(self, losses: dict[str, torch.Tensor], regularize: bool = False) -> torch.Tensor:
        """sum of loss_weights[name] * term, plus (with `regularize`) the fields' own regularisers, which are then
        logged as the term "regularization"."""
        total = sum((self.loss_weights[name] * value for name, value in losses.items()),
                    torch.zeros((), device=self.device))
        if regularize and (regularization := self.field_regularization()) is not None:
            losses["regularization"] = regularization
            total = total + regularization
        return total

    def depth_pairs(self, renders: Renders) -> list[DepthPair]:
        """Every masked depth loss of these renders: L_ap, L_av, ... (one per augmentation), then L_cfc."""
        pairs = [DepthPair(aug.name, aug.mask, aug.main_output(renders.main), renders.augmented[aug.name])
                 for aug in self.augmentations]
        if self.coarse_fine_mask is not None:
            pairs.append(DepthPair("cfc", self.coarse_fine_mask, renders.main.coarse, renders.main.fine))
        return pairs

    def masked_depth_loss(self, pair: DepthPair, rays: RayBatch) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The masked depth loss of one pair on train rays `rays`, and the fractions of its mask values (none when
        the mask trusts every ray)."""
        assert self.train_views is not None, "on_fit_start did not run"
        mask = pair.mask(self.train_views, rays, pair.main.depth.detach(), pair.other.depth.detach())
        z_main, z_other = pair.main.depth, pair.other.depth
        if self.hparams.depth_loss_space == "inverse":
            z_main, z_other = 1.0 / z_main.clamp_min(1e-6), 1.0 / z_other.clamp_min(1e-6)
        fractions = {} if mask is None else mask_fractions(mask)
        return masked_depth_loss(z_main, z_other, mask, self.hparams.supervision), fractions

    def field_regularization(self) -> torch.Tensor | None:
        """The sum of every field's own regulariser (`Field.regularization`), or None when no field has one."""
        fields = [self.nerf.coarse, self.nerf.fine, *(aug.field for aug in self.augmentations)]
        terms = [t for t in (f.regularization() for f in fields) if t is not None]
        return sum(terms) if terms else None

    def render_frame(self, frame: Frame) -> dict[str, torch.Tensor]:
        """Deterministic full-frame render: rgb [H, W, 3], depth [H, W], accumulation [H, W], coarse_depth [H, W]."""
        out = self.nerf.render_rays_chunked(frame.rays, self.hparams.chunk)
        return {k: v.reshape(frame.height, frame.width, *v.shape[1:]) for k, v in out.items()}

    def validation_step(self, batch: Frame, batch_idx: int) -> dict[str, torch.Tensor]:
        pred = self.render_frame(batch)
        frame_psnr = psnr(pred["rgb"][None], batch.rgb.reshape(pred["rgb"].shape)[None])[0]  # 8-bit, as in test
        self.log("val/psnr", frame_psnr, prog_bar=True, batch_size=1, sync_dist=True)
        return pred

    @torch.no_grad()
    def reliability_maps(self, view: int) -> dict[str, torch.Tensor]:
        """Masks [H, W] in {-1, 0, +1} of each augmentation and of L_cfc on train view `view`, at every pixel."""
        assert self.train_views is not None, "on_fit_start did not run"
        views, chunk = self.train_views, self.hparams.chunk
        h, w = views.height, views.width
        uv = pixel_grid(h, w, self.device)
        index = torch.full((h * w,), view, device=self.device)
        maps: dict[str, list[torch.Tensor]] = {}
        for start in range(0, h * w, chunk):
            part_view, part_uv = index[start : start + chunk], uv[start : start + chunk]
            rays = RayBatch(views.rays(part_view, part_uv, self.nerf.near), views.images[part_view, part_uv[:, 1],
                            part_uv[:, 0]], part_view, part_uv)  # fmt: skip
            for pair in self.depth_pairs(self.render(rays.rays, randomized=False)):
                m = pair.mask(views, rays, pair.main.depth, pair.other.depth)
                if m is not None:
                    maps.setdefault(pair.name, []).append(m)
        return {name: torch.cat(parts).reshape(h, w) for name, parts in maps.items()}

    def test_step(self, batch: Frame, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def predict_step(self, batch: Frame, batch_idx: int) -> dict[str, torch.Tensor]:
        return self.render_frame(batch)

    def configure_optimizers(self):
        groups = parameter_groups(self, self.group_lr)
        optimizer = (self.optimizer or default_optimizer)(groups)
        schedule = self.lr_scheduler(optimizer) if self.lr_scheduler is not None else ExponentialDecay(optimizer)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}
