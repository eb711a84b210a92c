"""The LightningModule: composes the NeRF, its augmentations and the objective; nothing else lives here.

`training_step` is one optimiser step of the paper's total loss (Sec. 4.4), L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav
+ l5 Lcfc (+ the fields' regularisers), the terms of `method.objective`. Pictures are the callbacks' job
(`simplenerf.run.callbacks`), evaluation (metrics, files) the `Evaluator`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass

import lightning as L
import torch
from jsonargparse.typing import PositiveInt
from lightning.pytorch.cli import LRSchedulerCallable, OptimizerCallable
from lightning.pytorch.strategies import DDPStrategy, ParallelStrategy
from torch import nn

from simplenerf.data.batches import Frame, RayBatch, SparseDepthBatch, TrainingBatch, UnseenPatches
from simplenerf.errors import SimpleNeRFError
from simplenerf.geometry.rays import pixel_grid
from simplenerf.geometry.views import Views
from simplenerf.method.augmentations import Augmentation
from simplenerf.method.losses import psnr_of_mse
from simplenerf.method.objective import (
    RESERVED_NAMES,
    ColorSpreadTerm,
    ConcentrationTerm,
    DistortionTerm,
    MaskedDepthTerm,
    Objective,
    RegularizerTerm,
    RenderedRays,
    Renders,
    Term,
    build_terms,
    part_loss,
)  # fmt: skip
from simplenerf.method.optim import ExponentialDecay, default_optimizer, parameter_groups
from simplenerf.method.reliability import ReliabilityMask, ReprojectionErrors
from simplenerf.metrics.scores import psnr
from simplenerf.model.nerf import FrameRender, NeRF


def ray_slices(n: int, size: int | None) -> list[slice]:
    """Consecutive slices of at most `size` (None: all n) of n rays."""
    size = size or n
    return [slice(start, min(start + size, n)) for start in range(0, n, size)]


@dataclass
class Part:
    """Rays rendered and backpropagated together: some random rays, some sparse-depth rays, or (a batch in one part)
    both, with each kind's share of the batch's rays of that kind; the batch's unseen patches, if any, are in one part
    whole (the last one)."""

    random: RayBatch | None = None
    sparse: SparseDepthBatch | None = None
    unseen: UnseenPatches | None = None
    random_share: float = 1.0
    sparse_share: float = 1.0


def batch_parts(batch: TrainingBatch, size: int | None) -> list[Part]:
    """The parts of a training batch: None, the whole batch in one part; else parts of at most `size` rays, the random
    rays first, then the sparse-depth rays (never mixed: no loss reads the colour of the sparse rays, so their parts
    render depth only), then the unseen patches in a part of their own (never cut: a patch's loss reads all of it)."""
    if size is None:
        return [Part(batch.random, batch.sparse, batch.unseen)]
    n = len(batch.random)
    parts = [Part(random=batch.random[s], random_share=(s.stop - s.start) / n) for s in ray_slices(n, size)]
    if batch.sparse is not None:
        m = len(batch.sparse)
        parts += [Part(sparse=batch.sparse[s], sparse_share=(s.stop - s.start) / m) for s in ray_slices(m, size)]
    if batch.unseen is not None:
        parts.append(Part(unseen=batch.unseen))
    return parts


@dataclass
class StepLoss:
    """A training step's objective, summed over its parts (all detached)."""

    loss: torch.Tensor  # [] the total loss
    values: dict[str, torch.Tensor]  # each term's value by name
    masks: dict[str, torch.Tensor]  # fractions of +1 / -1 / 0 rays of each mask, by "<term>/<plus|minus|zero>"
    fine_rgb: torch.Tensor  # [R, 3] main fine colours of the random rays


class SimpleNeRF(L.LightningModule):
    """SimpleNeRF: the main coarse/fine NeRF, its augmentations and its training objective."""

    def __init__(
        self,
        nerf: NeRF,
        augmentations: list[Augmentation] | None = None,
        objective: Objective = Objective(),
        optimizer: OptimizerCallable | None = None,
        lr_scheduler: LRSchedulerCallable | None = None,
        group_lr: dict[str, float] | None = None,
        chunk: PositiveInt = 8192,
        rays_per_backward: PositiveInt | None = None,
    ) -> None:
        """
        Args:
            nerf: the main model (coarse and fine fields, sampling, rendering).
            augmentations: simplified fields trained beside the main model (points and views in the paper); each
                adds its colour and sparse-depth losses and a masked depth term named after it. Empty: no
                augmentation (DS-NeRF when sparse depth is on).
            objective: loss weights and switches of the objective besides the augmentations' own (L_cfc's mask,
                supervision direction, depth space): `method.objective.Objective`.
            optimizer: the optimiser, given the parameter groups; null: Adam(lr 5e-4, betas 0.9 / 0.999), the
                release's.
            lr_scheduler: the learning-rate schedule, stepped every iteration; null: `ExponentialDecay(0.1, 250000)`,
                the release's (lr * 0.1^(step / 250000)).
            group_lr: learning rates of named parameter groups (a field's `parameter_groups()`, e.g. a grid's
                "grid" and "decoder"); the other groups take the optimiser's.
            chunk: rays per forward pass when rendering full frames (bounds memory, not results).
            rays_per_backward: render and backpropagate a batch in parts of at most this many rays, the random rays
                first, then the sparse-depth rays (depth only), as the release's 2048-ray sub-batches: the same loss
                and gradient, activation memory in proportion to the part (the random draws of jitter and noise
                differ from one part). null: the whole batch in one part.
        """
        super().__init__()
        self.automatic_optimization = False  # a step backpropagates its parts itself (`training_step`)
        self.save_hyperparameters(ignore=["nerf", "augmentations", "objective", "optimizer", "lr_scheduler"])
        self.nerf = nerf
        self.augmentations = nn.ModuleList(augmentations or [])
        self.objective = objective
        self.optimizer, self.lr_scheduler, self.group_lr = optimizer, lr_scheduler, dict(group_lr or {})
        names = [aug.name for aug in self.augmentations]
        if len(set(names)) != len(names) or set(RESERVED_NAMES) & set(names):
            raise ValueError(f"augmentation names must be unique and not one of {RESERVED_NAMES}, got {names}")
        fields = {"coarse": self.nerf.coarse, "fine": self.nerf.fine, **{a.name: a.field for a in self.augmentations}}
        # The terms by name; `run.callbacks.LossWeightSchedule` sets their weights per step (the warm-up).
        self.terms: dict[str, Term] = build_terms(objective, list(self.augmentations), fields)
        self.part_values: dict[str, torch.Tensor] = {}  # the terms' values in the part being backpropagated
        self.train_views: Views | None = None  # what the reliability masks look at (`set_train_views`)
        # Augmentations that training no longer renders: their own terms (masked depth, concentration) are 0 for
        # the rest of the run, so nothing they render reaches the main model again (set by LossWeightSchedule).
        self.retired: frozenset[str] = frozenset()

    @property
    def coarse_fine_mask(self) -> ReliabilityMask | None:
        """The reliability mask of L_cfc (None: no L_cfc)."""
        return self.objective.coarse_fine_mask

    @property
    def needs_masks(self) -> bool:
        """Whether training compares depths across train views (needs at least 2 train views)."""
        return any(isinstance(term, MaskedDepthTerm) for term in self.terms.values())

    def set_train_views(self, views: Views) -> None:
        """The train views the reliability masks reproject into; given by the CLI before `fit` (Python users: before
        `trainer.fit`, e.g. `model.set_train_views(datamodule.train_views)` after `datamodule.setup("fit")`)."""
        self.train_views = views

    def on_fit_start(self) -> None:
        if self.needs_masks:
            if self.train_views is None:
                raise SimpleNeRFError("the reliability masks need the train views: call "
                                      "model.set_train_views(datamodule.train_views) before trainer.fit")
            self.train_views = self.train_views.to(self.device)

    def render(self, rays, randomized: bool, color: bool = True, skip: frozenset[str] = frozenset()) -> Renders:
        """The main NeRF and every augmentation (but those named in `skip`) along `rays` (a `RayBundle`); `color`
        False: depths only (the augmentations are evaluated at the main model's samples, which carry the flag)."""
        main = self.nerf(rays, randomized=randomized, color=color)
        return Renders(main, {aug.name: aug.render(self.nerf, main, randomized) for aug in self.augmentations
                              if aug.name not in skip})

    def own_terms(self, augmentation: str) -> list[str]:
        """The terms only an augmentation's render feeds: its masked depth term, its mass concentration, and a
        distortion or colour-spread term given its render (its colour and sparse-depth losses are part of L_color and
        L_sd, which train only the augmentation itself)."""
        return [name for name, term in self.terms.items()
                if isinstance(term, MaskedDepthTerm) and term.other == augmentation
                or isinstance(term, ConcentrationTerm) and term.augmentation == augmentation
                or isinstance(term, (DistortionTerm, ColorSpreadTerm)) and term.render == augmentation]

    def step_terms(self) -> dict[str, Term]:
        """The terms of a training step: all of them but the regularisers of retired augmentations' fields (a retired
        augmentation is not rendered, so a regulariser alone would move its field, e.g. a grid's planes under their
        total variation, for nothing: the main model never reads it again)."""
        retired = [aug.field for aug in self.augmentations if aug.name in self.retired]
        return {name: term for name, term in self.terms.items()
                if not (isinstance(term, RegularizerTerm) and any(term.field is f for f in retired))}

    def training_step(self, batch: TrainingBatch, batch_idx: int) -> torch.Tensor:
        """One optimiser step of L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc (paper Sec. 4.4; `self.terms`):
        the batch's parts rendered and backpropagated (`backward_parts`), the gradients averaged over DDP processes
        once, the optimiser's step and the learning-rate schedule's. Returns the total loss (detached)."""
        optimizer, schedule = self.optimizers(), self.lr_schedulers()
        optimizer.zero_grad()
        strategy = self.trainer.strategy  # DDP: no gradient sync per part, one average after the last
        with strategy.block_backward_sync() if isinstance(strategy, ParallelStrategy) else nullcontext():
            step = self.backward_parts(batch, self.manual_backward)
        self.average_gradients()
        optimizer.step()
        schedule.step()
        self.log_step(step, batch)
        return step.loss

    def backward_parts(self, batch: TrainingBatch, backward: Callable[[torch.Tensor], None]) -> StepLoss:
        """Renders and backpropagates (`backward(loss)`) the batch's parts in turn (`batch_parts`), each part's
        terms weighted by its share of the rays (every term is a mean over rays: the parts' losses and gradients sum
        to the whole batch's); the fields' regularisers once, with the last part. Gradients accumulate in `.grad`."""
        parts = batch_parts(batch, self.hparams.rays_per_backward)
        total, values, masks, fine_rgb = torch.zeros((), device=self.device), {}, {}, []
        terms = self.step_terms()  # once per step: retirement changes between steps, not between parts
        for i, part in enumerate(parts):
            rendered = self.render_part(part)
            result = part_loss(terms, rendered, regularize=i == len(parts) - 1)
            self.part_values = result.values  # what `StopOnNonFiniteLoss` names when this part's loss is not finite
            if result.loss.requires_grad:  # (not when every term this part's rays feed has weight 0)
                backward(result.loss)  # frees this part's activations before the next part is rendered
            total = total + result.loss.detach()
            for name, value in result.values.items():
                values[name] = values[name] + value if name in values else value
            for name, value in result.masks.items():
                masks[name] = masks[name] + value if name in masks else value
            fine_rgb += [r.renders.main.fine.rgb.detach() for r in rendered if r.kind == "random"]
        return StepLoss(total, values, masks, torch.cat(fine_rgb))

    def render_part(self, part: Part) -> list[RenderedRays]:
        """A part's random and / or sparse rays rendered (a whole batch in one pass, then split; sparse rays alone:
        depth only), and its unseen patches (the main NeRF's depth only: no term reads more there)."""
        if part.random is not None and part.sparse is not None:
            both = self.render(part.random.rays.cat(part.sparse.rays), randomized=True, skip=self.retired)
            random, sparse = both.split(len(part.random))
        else:
            random = (self.render(part.random.rays, randomized=True, skip=self.retired)
                      if part.random is not None else None)
            sparse = (self.render(part.sparse.rays, randomized=True, color=False, skip=self.retired)
                      if part.sparse is not None else None)
        rendered = []
        if random is not None:
            errors = ReprojectionErrors(self.train_views, part.random) if self.train_views is not None else None
            rendered.append(RenderedRays("random", part.random, random, part.random_share, errors))
        if sparse is not None:
            rendered.append(RenderedRays("sparse", part.sparse, sparse, part.sparse_share))
        if part.unseen is not None:
            everything = frozenset(aug.name for aug in self.augmentations)
            unseen = self.render(part.unseen.rays, randomized=True, color=False, skip=everything)
            rendered.append(RenderedRays("unseen", part.unseen, unseen, 1.0))
        return rendered

    def average_gradients(self) -> None:
        """Under DDP, each process's accumulated gradient replaced by the processes' mean, in one all-reduce. Not
        DDP's own sync on the last part: that part may be sparse rays rendered without colour, whose backward leaves
        the colour branches out, and DDP's reducer syncs only what takes part in the synced backward."""
        strategy = self.trainer.strategy
        if not isinstance(strategy, DDPStrategy) or strategy.world_size < 2:
            return
        grads = [p.grad for p in self.parameters() if p.grad is not None]
        mean = strategy.reduce(torch.cat([g.reshape(-1) for g in grads]), reduce_op="mean")
        for grad, value in zip(grads, mean.split([g.numel() for g in grads]), strict=True):
            grad.copy_(value.view_as(grad))

    def log_step(self, step: StepLoss, batch: TrainingBatch) -> None:
        """Logs the step's loss, terms, mask fractions, term weights and the fine PSNR of its random rays."""
        # sync_dist: under DDP every rank trains on its own rays; the logged values are their mean (no-op otherwise).
        self.log_dict({f"train/loss_{name}": value for name, value in step.values.items()}, sync_dist=True)
        self.log_dict({f"train/mask_{name}": value for name, value in step.masks.items()}, sync_dist=True)
        self.log_dict({f"train_params/{name}": float(term.weight) for name, term in self.terms.items()})
        train_psnr = psnr_of_mse(step.fine_rgb, batch.random.rgb)
        self.log_dict({"train/loss": step.loss, "train/psnr_fine": train_psnr}, sync_dist=True)
        self.log("loss", step.loss, prog_bar=True, logger=False)

    def render_frame(self, frame: Frame) -> FrameRender:
        """Deterministic full-frame render: rgb [H, W, 3], depth [H, W], accumulation [H, W], coarse_depth [H, W]."""
        return self.nerf.render_rays_chunked(frame.rays, self.hparams.chunk).reshape(frame.height, frame.width)

    def validation_step(self, batch: Frame, batch_idx: int) -> FrameRender:
        pred = self.render_frame(batch)
        frame_psnr = psnr(pred.rgb[None], batch.rgb.reshape(pred.rgb.shape)[None])[0]  # 8-bit, as in test
        self.log("val/psnr", frame_psnr, prog_bar=True, batch_size=1, sync_dist=True)
        return pred

    @torch.no_grad()
    def reliability_maps(self, view: int) -> dict[str, torch.Tensor]:
        """Masks [H, W] in {-1, 0, +1} of each augmentation and of L_cfc on train view `view`, at every pixel."""
        assert self.train_views is not None, "set_train_views was not called"
        views, chunk = self.train_views, self.hparams.chunk
        h, w = views.height, views.width
        uv = pixel_grid(h, w, self.device)
        index = torch.full((h * w,), view, device=self.device)
        all_rays = views.rays(index, uv, self.nerf.near)
        render = self.nerf.render_rays_chunked(all_rays, chunk, self.augmentations)
        maps: dict[str, list[torch.Tensor]] = {}
        for start in range(0, h * w, chunk):  # the masks in chunks too: patch errors are [rays, k * k, ...]
            part = slice(start, start + chunk)
            part_view, part_uv = index[part], uv[part]
            rays = RayBatch(all_rays[part], views.images[part_view, part_uv[:, 1], part_uv[:, 0]], part_view, part_uv)
            errors = ReprojectionErrors(views, rays)
            for term in (t for t in self.terms.values() if isinstance(t, MaskedDepthTerm)):
                m = term.mask.judge(errors, term.main, render.depth_of(term.main)[part], term.other,
                                    render.depth_of(term.other)[part])
                if m is not None:
                    maps.setdefault(term.name, []).append(m)
        return {name: torch.cat(parts).reshape(h, w) for name, parts in maps.items()}

    def test_step(self, batch: Frame, batch_idx: int) -> FrameRender:
        return self.render_frame(batch)

    def predict_step(self, batch: Frame, batch_idx: int) -> FrameRender:
        return self.render_frame(batch)

    def configure_optimizers(self):
        groups = parameter_groups(self, self.group_lr)
        optimizer = (self.optimizer or default_optimizer)(groups)
        schedule = self.lr_scheduler(optimizer) if self.lr_scheduler is not None else ExponentialDecay(optimizer)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}
