"""Sample points along rays: what every field evaluated at them receives (the field contract's input).

`Samples` holds what does not depend on the field: NDC positions t, metric depths, interval lengths, the 3D points
(in NDC, the box [-1, 1]^3 of forward-facing scenes) and the unit view directions. Positional encodings are computed
on first use and cached, so the main field and every augmentation evaluated at the same points share them; a field
that does not use an encoding (a grid) never pays for it. `color` says whether any loss reads the colour rendered at
these samples (the sparse-depth rays' losses read depth only): where it is False a field may skip its colour branch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from simplenerf.model.encodings import encoded_dim, positional_encoding


@dataclass(eq=False)
class Samples:
    """S samples along each of R rays."""

    t: torch.Tensor  # [R, S] NDC positions in [0, 1]
    t_metric: torch.Tensor  # [R, S] camera z-depths
    delta: torch.Tensor  # [R, S] NDC interval lengths
    positions: torch.Tensor  # [R, S, 3] the points in NDC
    directions: torch.Tensor  # [R, 3] unit world-space view directions
    color: bool = True  # False: nothing reads the colour here; fields may return rgb None
    _encodings: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)
    _parent: tuple[Samples, slice] | None = field(default=None, repr=False)  # a range of these rays (`__getitem__`)

    def __getitem__(self, index: slice) -> Samples:
        """The samples of a range of the rays. Their encodings are slices (views) of these samples' encodings,
        computed here on first use, so pieces of one batch share one encoding with every field at the same points."""
        return Samples(self.t[index], self.t_metric[index], self.delta[index], self.positions[index],
                       self.directions[index], self.color, _parent=(self, index))

    def encoded_positions(self, bands: int) -> torch.Tensor:
        """gamma(p, 0, bands) of the points: [R, S, 3 (2 bands + 1)]."""
        return self._encoding("positions", self.positions, bands)

    def encoded_directions(self, bands: int) -> torch.Tensor:
        """gamma(v, 0, bands) of the view directions: [R, 3 (2 bands + 1)]."""
        return self._encoding("directions", self.directions, bands)

    def _encoding(self, name: str, x: torch.Tensor, bands: int) -> torch.Tensor:
        if self._parent is not None:
            parent, index = self._parent
            source = parent.positions if name == "positions" else parent.directions
            return parent._encoding(name, source, bands)[index]
        # gamma's blocks are ordered by frequency, so fewer bands are a leading slice of the cached encoding.
        cached = self._encodings.get(name)
        if cached is None or cached.shape[-1] < encoded_dim(3, bands):
            cached = self._encodings[name] = positional_encoding(x, bands)
        return cached[..., : encoded_dim(3, bands)]
