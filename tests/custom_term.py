"""A user's own loss term, defined outside the package and plugged in from YAML by class_path
(docs/architecture.md "Extending"; `model.objective.terms`).

`OpacityTerm` pushes a render's accumulated opacity toward 1 on the random rays: mean over rays of (1 - acc)^2.
"""

from __future__ import annotations

import torch

from simplenerf.method.objective import RenderedRays, Term, TermValue


class OpacityTerm(Term):
    """mean((1 - accumulation)^2) of one render ("coarse", "fine" or an augmentation's name) on the random rays."""

    def __init__(self, weight: float = 0.01, render: str = "fine", name: str = "opacity") -> None:
        """
        Args:
            weight: the term's weight.
            render: which render's accumulation it reads.
            name: the term's name (logged as train/loss_<name>).
        """
        super().__init__(name, weight, ("random",))
        self.render = render

    def value(self, rendered: RenderedRays | None) -> TermValue:
        assert rendered is not None
        accumulation = rendered.renders[self.render].accumulation
        return TermValue(torch.mean((1.0 - accumulation) ** 2))
