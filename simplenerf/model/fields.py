"""Radiance fields: the field contract and the NeRF MLP F1 (density + feature) and F2 (colour): paper Sec. 3 and
its architecture figure; the layers as in the release's src/models/SimpleNeRF01.py (DS-NeRF's network: supplement,
Implementation Details).

The contract: a `Field` is an `nn.Module` called with the `Samples` of a batch of rays and returning `FieldOutputs`
(raw density and colour per sample). It reads what it needs from the samples (raw NDC positions, directions, or their
cached positional encodings). The NeRF's coarse and fine fields and every augmentation's field are `Field`s, chosen
by `class_path` in YAML, so an MLP, a grid or a user's own field plug in the same way.

`RadianceField`, the paper's MLP, covers the main field and its simplified variants as configuration of the same
parts:
- `density_bands` l: the trunk F1 sees gamma(p, 0, l) instead of gamma(p, 0, L) (points augmentation, l = 3);
- `residual_bands_to_color`: F2 also gets the bands F1 lost, gamma(p, l, L) (points augmentation);
- `view_dependent=False`: no direction input; the trunk's last layer outputs density and RGB (views augmentation);
- `num_layers`, `width`: the network size (smaller-network ablation).

The encodings come from the samples' cache (`Samples.encoded_positions`), so the main field and every augmentation
evaluated at the same points share that work.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from jsonargparse.typing import NonNegativeInt, PositiveInt
from torch import nn

from simplenerf.model.encodings import band_slice, encoded_dim
from simplenerf.model.samples import Samples


@dataclass
class FieldOutputs:
    """Raw field outputs at sample points."""

    raw_density: torch.Tensor  # [R, S] before noise and ReLU
    rgb: torch.Tensor | None  # [R, S, 3] in [0, 1]; may be None when `samples.color` is False


class Field(nn.Module):
    """A radiance field: `field(samples) -> FieldOutputs`. Subclasses implement `forward`; where `samples.color` is
    False no loss reads the colour, so a field may skip computing it (return rgb None): an optimisation, not a duty."""

    def forward(self, samples: Samples) -> FieldOutputs:
        raise NotImplementedError

    def parameter_groups(self) -> dict[str, list[nn.Parameter]]:
        """This field's parameters by optimiser group name (`SimpleNeRF.group_lr` gives a group its own learning
        rate); one group "mlp" by default. A grid returns e.g. {"grid": ..., "decoder": ...}."""
        return {"mlp": list(self.parameters())}

    def regularizers(self) -> dict[str, float]:
        """The field's own regularisers (e.g. a grid's total variation) by name, with their initial weights: each is a
        term `<name>_<field>` of the objective (`method.objective`, e.g. `tv_fine`) whose weight a schedule may set
        and the logger shows. None by default."""
        return {}

    def regularization(self, name: str) -> torch.Tensor:
        """The unweighted value [] of the regulariser `name` (one of `regularizers()`), once per step."""
        raise KeyError(f"{type(self).__name__} has no regulariser {name!r}")


class RadianceField(Field):
    """An MLP field sigma, c = F(gamma(p), gamma(v))."""

    def __init__(
        self,
        point_bands: NonNegativeInt = 10,
        view_bands: NonNegativeInt = 4,
        density_bands: int | None = None,
        residual_bands_to_color: bool = False,
        view_dependent: bool = True,
        num_layers: PositiveInt = 8,
        width: PositiveInt = 256,
        skip_layer: int | None = 5,
        color_width: PositiveInt = 128,
    ) -> None:
        """
        Args:
            point_bands: L_p, bands of the point encoding gamma(p, 0, L_p) (10 in the paper).
            view_bands: L_v, bands of the direction encoding (4 in the paper).
            density_bands: bands the density trunk uses, gamma(p, 0, l); None = all L_p (main field).
            residual_bands_to_color: feed the bands the trunk does not use, gamma(p, l, L_p), to the colour branch.
            view_dependent: colour depends on the view direction; if False the trunk outputs density and RGB.
            num_layers: linear layers of the trunk.
            width: width of the trunk.
            skip_layer: index of the trunk layer that receives the encoded point again (5 = before the 6th layer).
            color_width: hidden width of the colour branch.
        """
        super().__init__()
        density_bands = point_bands if density_bands is None else density_bands
        if not 0 <= density_bands <= point_bands:
            raise ValueError(f"density_bands must be in [0, {point_bands}], got {density_bands}")
        if skip_layer is not None and not 0 < skip_layer < num_layers:
            raise ValueError(f"skip_layer must be in (0, {num_layers}), got {skip_layer}")
        self.point_bands, self.view_bands = point_bands, view_bands
        self.view_dependent = view_dependent
        self.skip_layer = skip_layer
        self.trunk_slice = band_slice(3, 0, density_bands, include_input=True)
        self.residual_slice = band_slice(3, density_bands, point_bands, include_input=False)
        self.residual_bands_to_color = residual_bands_to_color
        in_dim = encoded_dim(3, density_bands)

        layers = []
        for i in range(num_layers):
            fan_in = in_dim if i == 0 else width
            if i == skip_layer:
                fan_in += in_dim
            layers.append(nn.Linear(fan_in, width))
        self.trunk = nn.ModuleList(layers)

        if view_dependent:
            residual_dim = 3 * 2 * (point_bands - density_bands) if residual_bands_to_color else 0
            self.density_head = nn.Linear(width, 1)
            self.feature = nn.Linear(width, width)
            self.color = nn.Sequential(
                nn.Linear(width + residual_dim + encoded_dim(3, view_bands), color_width),
                nn.ReLU(),
                nn.Linear(color_width, 3),
            )
        else:
            if residual_bands_to_color:
                raise ValueError("residual_bands_to_color needs a colour branch (view_dependent=True)")
            self.output = nn.Linear(width, 4)

    def forward(self, samples: Samples) -> FieldOutputs:
        """Density and colour at the samples from gamma(p, 0, L_p) and, if view-dependent, gamma(v, 0, L_v)."""
        points_enc = samples.encoded_positions(self.point_bands)  # [R, S, 3(2 L_p + 1)]
        x = points_enc[..., self.trunk_slice]
        h = x
        for i, layer in enumerate(self.trunk):
            h = torch.relu(layer(torch.cat([h, x], dim=-1) if i == self.skip_layer else h))
        if not samples.color:  # density only: the colour branch is skipped, the density is the same
            if self.view_dependent:
                raw = self.density_head(h)
            else:  # the density is the first output of the joint head
                raw = nn.functional.linear(h, self.output.weight[:1], self.output.bias[:1])
            return FieldOutputs(raw_density=raw[..., 0], rgb=None)
        if not self.view_dependent:
            out = self.output(h)
            return FieldOutputs(raw_density=out[..., 0], rgb=torch.sigmoid(out[..., 1:]))
        color_in = [self.feature(h)]
        if self.residual_bands_to_color:
            color_in.append(points_enc[..., self.residual_slice])
        dirs_enc = samples.encoded_directions(self.view_bands)  # [R, 3(2 L_v + 1)]
        color_in.append(dirs_enc[:, None, :].expand(*h.shape[:-1], dirs_enc.shape[-1]))
        rgb = torch.sigmoid(self.color(torch.cat(color_in, dim=-1)))
        return FieldOutputs(raw_density=self.density_head(h)[..., 0], rgb=rgb)
