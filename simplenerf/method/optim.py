"""Optimisation: parameter groups per field and the exponential learning-rate decay of the release.

Optimiser and schedule are configuration (`model.optimizer`, `model.lr_scheduler`: any torch optimiser / scheduler
by `class_path`); `model.group_lr` gives a parameter group (e.g. a grid's "grid" and "decoder") its own learning rate.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import nn
from torch.optim.lr_scheduler import LambdaLR

from simplenerf.model.fields import Field


def parameter_groups(module: nn.Module, group_lr: dict[str, float]) -> list[dict]:
    """The optimiser's parameter groups of `module`: each `Field`'s `parameter_groups()` merged by name (in module
    order), then every other parameter in a group "other". A name in `group_lr` gets that learning rate; the others
    take the optimiser's.

    Raises:
        ValueError: `group_lr` names a group that no field has.
    """
    groups: dict[str, list[nn.Parameter]] = {}
    seen: set[int] = set()
    for sub in module.modules():
        if isinstance(sub, Field) and not any(id(p) in seen for p in sub.parameters()):
            for name, params in sub.parameter_groups().items():
                groups.setdefault(name, []).extend(params)
                seen.update(id(p) for p in params)
    rest = [p for p in module.parameters() if id(p) not in seen]
    if rest:
        groups.setdefault("other", []).extend(rest)
    unknown = set(group_lr) - set(groups)
    if unknown:
        raise ValueError(f"group_lr names {sorted(unknown)}, but the parameter groups are {sorted(groups)}")
    return [{"params": params, "name": name, **({"lr": group_lr[name]} if name in group_lr else {})}
            for name, params in groups.items()]


class ExponentialDecay(LambdaLR):
    """lr(step) = lr * decay_rate ** (step / decay_steps), stepped every iteration. The authors' release: 0.1 over
    250000 steps (ends near 2e-4 at 100k from 5e-4; the published scores); the paper's text ("decay to 5e-6"):
    0.01 over 100000 steps."""

    def __init__(self, optimizer: torch.optim.Optimizer, decay_rate: float = 0.1, decay_steps: int = 250000) -> None:
        """
        Args:
            optimizer: the optimiser whose learning rates decay.
            decay_rate: factor reached after `decay_steps` steps.
            decay_steps: steps over which the learning rate falls by `decay_rate`.
        """
        if not decay_rate > 0 or decay_steps <= 0:
            raise ValueError(f"decay_rate and decay_steps must be positive, got {decay_rate}, {decay_steps}")
        self.decay_rate, self.decay_steps = decay_rate, decay_steps
        super().__init__(optimizer, self.factor)

    def factor(self, step: int) -> float:
        """The learning-rate multiplier at `step`."""
        return self.decay_rate ** (step / self.decay_steps)


def default_optimizer(params: Iterable) -> torch.optim.Optimizer:
    """The release's optimiser: Adam, lr 5e-4, betas (0.9, 0.999)."""
    return torch.optim.Adam(params, lr=5e-4, betas=(0.9, 0.999))
