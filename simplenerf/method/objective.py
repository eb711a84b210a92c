"""SimpleNeRF's objective (paper Sec. 4.4) as typed terms: L = l1 Lcolor + l2 Lsd + l3 Lap + l4 Lav + l5 Lcfc, plus
each field's own regulariser (e.g. a grid's total variation): L = sum over terms of term.weight * term value.

A term has a `name` (its value is logged as `train/loss_<name>`, its weight as `train_params/<name>`, and a
`run.callbacks.LossWeightSchedule` sets its weight by that name), the rays it `reads` (the batch's random rays, its
sparse-depth rays, or none: a regulariser, evaluated once per step) and a `weight`. A term whose weight is 0 is not
computed (during the warm-up the masked terms cost nothing, not even their masks).

A ray term's value is a mean over the rays it reads, so a batch may be rendered in parts (`method.module.SimpleNeRF`):
the parts' values, each weighted by its share of the batch's rays of that kind, sum to the whole batch's value.

Every term, the paper's and a user's, is a `Term` (one contract: `value`). A user's term is named by `class_path` in
`model.objective.terms` and summed after the built-in ones (docs/architecture.md "Extending";
`tests/custom_term.py` is an example).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import torch

from simplenerf.data.batches import RayBatch, SparseDepthBatch, UnseenPatches
from simplenerf.method.losses import (
    coarse_fine_sparse_loss,
    color_loss,
    color_spread_loss,
    depth_smoothness_loss,
    distortion_loss,
    expected_ndc_t,
    mass_concentration_loss,
    sparse_depth_loss,
)
from simplenerf.method.reliability import (
    Direction,
    ReliabilityMask,
    ReprojectionErrors,
    mask_fractions,
    masked_depth_loss,
)
from simplenerf.model.fields import Field
from simplenerf.model.nerf import NeRFOutputs
from simplenerf.model.rendering import RenderOutputs

RayKind = Literal["random", "sparse", "unseen"]
# Names of renders and terms that an augmentation may not take.
RESERVED_NAMES = ("coarse", "fine", "color", "sparse_depth", "coarse_sparse_depth", "cfc")


@dataclass
class Objective:
    """The settings of the loss besides the augmentations' own (`Augmentation.mask`, `depth_weight`).

    Args:
        color_weight: lambda_1, weight of the colour loss (main coarse, main fine and each augmentation).
        sparse_depth_weight: lambda_2, weight of DS-NeRF's sparse-depth loss (main fine and each augmentation; used
            when the data module serves sparse-depth rays, `sparse_rays_per_batch` > 0).
        coarse_sparse_depth_weight: weight of the same sparse-depth loss on the main coarse depth (the term
            "coarse_sparse_depth"); 0 (the paper and the release): off, and SfM depth reaches the main coarse field
            only through L_cfc's sparse-ray part once L_cfc is on. Not in the paper: on the grid the coarse field
            otherwise starts L_cfc with a depth it was never taught (docs/results.md, 19 and 23).
        coarse_fine_mask: reliability mask of the coarse-fine consistency loss L_cfc; null disables L_cfc.
        coarse_fine_weight: lambda_5, weight of L_cfc (a warm-up schedule may set it per step).
        coarse_fine_on_sparse_rays: as the release, L_cfc also has an unmasked (z_coarse - sg(z_fine))^2 on the
            sparse-depth rays: the only path by which SfM depth reaches the main coarse field.
        supervision: `bidirectional`: where a mask is -1 the other depth is trained toward the main one (the paper's
            equations); `one_way`: only mask +1 rays train the main depth (what the release trains; the default: on
            the CPU benchmark it was slightly better in colour, within noise in depth).
        depth_loss_space: what L_ap, L_av and L_cfc compare: `metric` depth (the paper and the release) or `inverse`
            depth 1 / z, bounded by 1 / near. Metric depth grows without bound towards the NDC far plane, where a few
            rays can dominate these squared losses (docs/results.md "Grid backbone"). The masks compare metric depth.
        depth_error_limit: null (the paper): L_ap, L_av and L_cfc square each ray's depth difference; a depth
            difference (in `depth_loss_space` units): past it they grow linearly (`reliability.limited_square`, a
            Huber loss), so that a few rays whose depth runs to the far plane cannot swamp a step and Adam's moment
            estimates with it. The sparse-ray part of L_cfc stays squared.
        coarse_fine_supervision: the direction of L_cfc alone; null: `supervision`. `one_way` with a `bidirectional`
            `supervision` trains the coarse depth toward the fine one but never the fine toward the coarse, while
            L_ap and L_av stay bidirectional (docs/results.md "Simple-RF's augmentation on the grid").
        fine_concentration_weight: weight of Simple-RF's mass concentration (`losses.mass_concentration_loss`, the
            term "fine_concentration") on the main fine render's ray weights; 0 (the paper): off. Not in the paper
            nor in Simple-RF, which put it on the augmentation only (docs/results.md "Simple-RF's augmentation on the
            grid").
        concentration_bins: the bins of that loss.
        distortion_weight: weight of Mip-NeRF 360's distortion loss (`losses.distortion_loss`) on the main coarse
            and main fine renders' ray weights (the terms "coarse_distortion" and "fine_distortion", each scheduled
            on its own); 0 (the paper): off. Not in the paper; K-Planes and Mip-NeRF 360 use it against the fog
            that every depth loss of the paper allows, since they compare the mean depth only (docs/results.md
            "Where the blur and the streaks come from").
        color_spread_weight: weight of the spread of the samples' colours about each ray's rendered colour
            (`losses.color_spread_loss`) on the main coarse and fine renders (the terms "coarse_color_spread" and
            "fine_color_spread", each scheduled on its own); 0: off. Not in the paper; against renders whose colour is a
            blend along the ray, which smear from other views (docs/results.md "Where the blur and the streaks come
            from", 13).
        depth_smoothness_weight: weight of RegNeRF's depth smoothness (`losses.depth_smoothness_loss`) on the expected
            NDC t of the main coarse and fine renders of patches from unseen cameras (the terms
            "coarse_depth_smoothness" and "fine_depth_smoothness", each scheduled on its own; the data module's
            `unseen_patches_per_batch` serves the patches); 0: off. Not in the paper; against depth that is free
            wherever the photos leave it so (plain walls), which other views see as streaks (docs/results.md
            "Where the blur and the streaks come from", 24).
        terms: further terms (`Term` subclasses by `class_path`, e.g. a user's own), summed after the built-in ones;
            each is logged and scheduled by its `name` like them.
    """

    color_weight: float = 1.0
    sparse_depth_weight: float = 0.1
    coarse_sparse_depth_weight: float = 0.0
    coarse_fine_mask: ReliabilityMask | None = None
    coarse_fine_weight: float = 0.1
    coarse_fine_on_sparse_rays: bool = True
    supervision: Direction = "one_way"
    depth_loss_space: Literal["metric", "inverse"] = "metric"
    depth_error_limit: float | None = None
    coarse_fine_supervision: Direction | None = None
    fine_concentration_weight: float = 0.0
    concentration_bins: int = 5
    distortion_weight: float = 0.0
    color_spread_weight: float = 0.0
    depth_smoothness_weight: float = 0.0
    terms: list[Term] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.depth_error_limit is not None and not self.depth_error_limit > 0:
            raise ValueError(f"depth_error_limit must be a positive depth difference or null, got "
                             f"{self.depth_error_limit}")


@dataclass
class Renders:
    """Every render of a batch of rays: the main coarse and fine NeRF and each augmentation, by name."""

    main: NeRFOutputs
    augmented: dict[str, RenderOutputs]

    def __getitem__(self, name: str) -> RenderOutputs:
        """A render by name: "coarse" or "fine" (the main NeRF's) or an augmentation's."""
        if name in ("coarse", "fine"):
            return self.main.coarse if name == "coarse" else self.main.fine
        return self.augmented[name]

    def split(self, n: int) -> tuple[Renders, Renders]:
        """The renders of the first n rays (a training batch's random rays) and of the rest (its sparse rays)."""
        (first, rest), augmented = self.main.split(n), self.augmented.items()
        return Renders(first, {k: r[:n] for k, r in augmented}), Renders(rest, {k: r[n:] for k, r in augmented})


@dataclass
class RenderedRays:
    """Rays of one kind from one part of a training batch, with their renders: what a ray term reads."""

    kind: RayKind
    rays: RayBatch | SparseDepthBatch | UnseenPatches
    renders: Renders
    share: float  # this part's fraction of the batch's rays of this kind
    errors: ReprojectionErrors | None = None  # random rays: their patch reprojection errors, shared by the masks


@dataclass
class TermValue:
    """A term's value [] on some rays, and the fractions of its mask's values there, by "<plus|minus|zero>"."""

    value: torch.Tensor
    masks: dict[str, torch.Tensor] = field(default_factory=dict)


class Term(ABC):
    """One weighted term of the total loss: `weight * value`.

    The contract is `value`. A term that reads rays ("random": the batch's random rays, with their colours and patch
    reprojection errors; "sparse": its sparse-depth rays) is given each part's rendered rays of a kind it reads and
    returns a mean over them. A term that reads none (a regulariser) is evaluated once per step, given None.

    Args:
        name: logged as `train/loss_<name>`; a `run.callbacks.LossWeightSchedule` schedules the weight by it. Unique.
        weight: the term's weight (0: not computed).
        reads: the kinds of rays the term reads: a tuple of "random" / "sparse"; empty: once per step.
    """

    def __init__(self, name: str, weight: float, reads: tuple[RayKind, ...]) -> None:
        self.name, self.weight, self.reads = name, weight, tuple(reads)

    @abstractmethod
    def value(self, rendered: RenderedRays | None) -> TermValue:
        """The term's value [] on `rendered` (rays of a kind it reads; a mean over them), or, for a term that reads
        no rays, None: its value for the step."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, weight={self.weight}, reads={self.reads})"


class ColorTerm(Term):
    """L_color (lambda_1) on the random rays: main coarse, main fine and each augmentation."""

    def __init__(self, weight: float) -> None:
        super().__init__("color", weight, ("random",))

    def value(self, rendered: RenderedRays) -> TermValue:
        renders = rendered.renders
        return TermValue(color_loss([renders.main.coarse, renders.main.fine, *renders.augmented.values()],
                                    rendered.rays.rgb))


class SparseDepthTerm(Term):
    """DS-NeRF's L_sd (lambda_2) on the sparse-depth rays: main fine and each augmentation (not main coarse); with
    `coarse`, the term "coarse_sparse_depth": the same loss on the main coarse depth alone."""

    def __init__(self, weight: float, coarse: bool = False) -> None:
        super().__init__("coarse_sparse_depth" if coarse else "sparse_depth", weight, ("sparse",))
        self.coarse = coarse

    def value(self, rendered: RenderedRays) -> TermValue:
        renders, rays = rendered.renders, rendered.rays
        depths = [renders.main.coarse] if self.coarse else [renders.main.fine, *renders.augmented.values()]
        return TermValue(sparse_depth_loss(depths, rays.depth, rays.weight))


class MaskedDepthTerm(Term):
    """A masked depth loss between the main model's render `main` and another render `other` (paper eqs. 3, 4, 7):
    L_ap, L_av (an augmentation and the main coarse depth) or L_cfc (main fine and main coarse) on the random rays;
    for L_cfc, optionally the release's unmasked (z_coarse - sg(z_fine))^2 on the sparse-depth rays as well."""

    def __init__(self, name: str, weight: float, mask: ReliabilityMask, main: str, other: str,
                 supervision: Direction, depth_loss_space: str, on_sparse_rays: bool = False,
                 depth_error_limit: float | None = None) -> None:
        super().__init__(name, weight, ("random", "sparse") if on_sparse_rays else ("random",))
        self.mask, self.main, self.other = mask, main, other
        self.supervision, self.depth_loss_space = supervision, depth_loss_space
        self.depth_error_limit = depth_error_limit

    def value(self, rendered: RenderedRays) -> TermValue:
        main, other = rendered.renders[self.main], rendered.renders[self.other]
        if rendered.kind == "sparse":
            return TermValue(coarse_fine_sparse_loss(main, other))
        assert rendered.errors is not None, "the train views were not given (SimpleNeRF.set_train_views)"
        mask = self.mask.judge(rendered.errors, self.main, main.depth.detach(), self.other, other.depth.detach())
        z_main, z_other = main.depth, other.depth
        if self.depth_loss_space == "inverse":
            z_main, z_other = 1.0 / z_main.clamp_min(1e-6), 1.0 / z_other.clamp_min(1e-6)
        fractions = {} if mask is None else mask_fractions(mask)
        return TermValue(masked_depth_loss(z_main, z_other, mask, self.supervision, self.depth_error_limit), fractions)


class ConcentrationTerm(Term):
    """Simple-RF's mass concentration on an augmentation's ray weights (`losses.mass_concentration_loss`; Simple-RF,
    arXiv 2404.19015), on the random rays: against a translucent augmented depth winning a reliability mask."""

    def __init__(self, augmentation: str, weight: float, bins: int) -> None:
        """`augmentation`: the render's name (an augmentation's, or "fine")."""
        super().__init__(f"{augmentation}_concentration", weight, ("random",))
        self.augmentation, self.bins = augmentation, bins

    def value(self, rendered: RenderedRays) -> TermValue:
        return TermValue(mass_concentration_loss(rendered.renders[self.augmentation].weights, self.bins))


class DistortionTerm(Term):
    """Mip-NeRF 360's distortion loss on a render's ray weights (`losses.distortion_loss`), on the random rays.

    By default the main render of `stage`; with `render`, that render (an augmentation's, evaluated at the main
    model's `stage` samples), as a user's term in `Objective.terms`, named "<render>_distortion"."""

    def __init__(self, stage: Literal["coarse", "fine"], weight: float, render: str | None = None) -> None:
        self.render = render or stage
        super().__init__(f"{self.render}_distortion", weight, ("random",))
        self.stage = stage

    def value(self, rendered: RenderedRays) -> TermValue:
        samples = rendered.renders.main.samples(self.stage)
        return TermValue(distortion_loss(rendered.renders[self.render].weights, samples.t))


class ColorSpreadTerm(Term):
    """The spread of a render's sample colours about its rendered colour (`losses.color_spread_loss`), on the random
    rays: by default the main render of `stage`; with `render`, that render (e.g. an augmentation's), as a user's
    term in `Objective.terms`, named "<render>_color_spread"."""

    def __init__(self, stage: Literal["coarse", "fine"], weight: float, render: str | None = None) -> None:
        self.render = render or stage
        super().__init__(f"{self.render}_color_spread", weight, ("random",))
        self.stage = stage

    def value(self, rendered: RenderedRays) -> TermValue:
        render = rendered.renders[self.render]
        return TermValue(color_spread_loss(render.weights, render.sample_rgb, render.rgb))


class DepthSmoothnessTerm(Term):
    """RegNeRF's depth smoothness of a main render's expected NDC t (`losses.expected_ndc_t`,
    `losses.depth_smoothness_loss`), on the patches from unseen cameras."""

    def __init__(self, stage: Literal["coarse", "fine"], weight: float) -> None:
        super().__init__(f"{stage}_depth_smoothness", weight, ("unseen",))
        self.stage = stage

    def value(self, rendered: RenderedRays) -> TermValue:
        samples = rendered.renders.main.samples(self.stage)
        depth = expected_ndc_t(rendered.renders[self.stage].weights, samples.t)
        return TermValue(depth_smoothness_loss(depth, rendered.rays.size))


class RegularizerTerm(Term):
    """A field's own regulariser (`Field.regularizers`, e.g. a grid's total variation), once per step."""

    def __init__(self, name: str, weight: float, field: Field, regularizer: str) -> None:
        super().__init__(name, weight, ())
        self.field, self.regularizer = field, regularizer

    def value(self, rendered: RenderedRays | None = None) -> TermValue:
        return TermValue(self.field.regularization(self.regularizer))


def build_terms(objective: Objective, augmentations: Sequence, fields: Mapping[str, Field]) -> dict[str, Term]:
    """The terms by name, in the order they are summed: colour, sparse depth (main fine and augmentations, then main
    coarse), one masked depth term per augmentation
    (named after it), Simple-RF's mass concentration of those that have one ("<name>_concentration"), the distortion
    of the main renders ("coarse_distortion", "fine_distortion"), the spread of their colours ("coarse_color_spread",
    "fine_color_spread"), their depth smoothness on unseen patches ("coarse_depth_smoothness",
    "fine_depth_smoothness"), L_cfc ("cfc"), then each field's regularisers
    ("<regulariser>_<field>", e.g. "tv_fine"), then `objective.terms`.

    Args:
        augmentations: `method.augmentations.Augmentation`s. fields: the fields by name ("coarse", "fine" and the
            augmentations' names).
    """
    terms: list[Term] = [ColorTerm(objective.color_weight), SparseDepthTerm(objective.sparse_depth_weight),
                         SparseDepthTerm(objective.coarse_sparse_depth_weight, coarse=True)]
    depth = {"supervision": objective.supervision, "depth_loss_space": objective.depth_loss_space,
             "depth_error_limit": objective.depth_error_limit}
    for aug in augmentations:
        terms.append(MaskedDepthTerm(aug.name, aug.depth_weight, aug.mask, aug.stage, aug.name, **depth))
    terms += [ConcentrationTerm(aug.name, aug.concentration_weight, aug.concentration_bins) for aug in augmentations
              if aug.concentration_weight is not None]
    terms.append(ConcentrationTerm("fine", objective.fine_concentration_weight, objective.concentration_bins))
    terms += [DistortionTerm(stage, objective.distortion_weight) for stage in ("coarse", "fine")]
    terms += [ColorSpreadTerm(stage, objective.color_spread_weight) for stage in ("coarse", "fine")]
    terms += [DepthSmoothnessTerm(stage, objective.depth_smoothness_weight) for stage in ("coarse", "fine")]
    if objective.coarse_fine_mask is not None:
        cfc_depth = depth | {"supervision": objective.coarse_fine_supervision or objective.supervision}
        terms.append(MaskedDepthTerm("cfc", objective.coarse_fine_weight, objective.coarse_fine_mask, "coarse", "fine",
                                     on_sparse_rays=objective.coarse_fine_on_sparse_rays, **cfc_depth))
    for place, f in fields.items():
        terms += [RegularizerTerm(f"{name}_{place}", weight, f, name) for name, weight in f.regularizers().items()]
    terms += objective.terms
    names = [t.name for t in terms]
    if len(set(names)) != len(names):
        raise ValueError(f"loss term names must be unique, got {names}")
    stages = {"coarse": "coarse", "fine": "fine", **{aug.name: aug.stage for aug in augmentations}}
    for t in terms:
        if isinstance(t, (DistortionTerm, ColorSpreadTerm)) and t.render not in stages:
            raise ValueError(f"the term {t.name!r} reads the render {t.render!r}, which the model does not have "
                             f"(its renders: {', '.join(stages)})")
        if isinstance(t, DistortionTerm) and stages[t.render] != t.stage:
            raise ValueError(f"the term {t.name!r} needs stage {stages[t.render]!r}: the render {t.render!r} is "
                             f"evaluated at the main model's {stages[t.render]} samples, not its {t.stage} ones")
    return {t.name: t for t in terms}


@dataclass
class PartLoss:
    """The objective on one part of a training batch."""

    loss: torch.Tensor  # [] sum of weight * share * value over the part's terms, with its graph
    values: dict[str, torch.Tensor]  # share * value by term name, detached
    masks: dict[str, torch.Tensor]  # share * mask fractions by "<term>/<plus|minus|zero>", detached


def part_loss(terms: Mapping[str, Term], parts: Sequence[RenderedRays], regularize: bool) -> PartLoss:
    """The weighted terms on rendered rays (a part's random and / or sparse rays), plus, with `regularize`, the
    regularisers (once per step). Terms of weight 0 are not computed."""
    active = [t for t in terms.values() if t.weight != 0]
    kind_losses, values, masks = [], {}, {}
    for rendered in parts:
        loss = torch.zeros((), device=rendered.rays.rays.origins.device)
        for term in (t for t in active if rendered.kind in t.reads):
            result = term.value(rendered)
            value = rendered.share * result.value
            loss = loss + term.weight * value
            values[term.name] = values[term.name] + value.detach() if term.name in values else value.detach()
            for key, fraction in result.masks.items():
                key = f"{term.name}/{key}"
                masks[key] = masks.get(key, 0.0) + rendered.share * fraction
        kind_losses.append(loss)
    total = sum(kind_losses)
    if regularize:
        for term in (t for t in active if not t.reads):
            value = term.value(None).value
            total = total + term.weight * value
            values[term.name] = value.detach()
    return PartLoss(total, values, masks)
