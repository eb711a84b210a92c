"""Augmentations ("simplifiers", paper Sec. 4.1): simpler NeRFs trained beside the main one to supervise its depth.

An augmentation is a field evaluated at the main model's sample points (the coarse ones in the paper), trained with
the colour and sparse-depth losses, and tied to the main model's depth there by a masked depth loss whose mask comes
from its own `ReliabilityMask`. The simplifications themselves are configuration of `RadianceField`:

- points augmentation: `RadianceField(density_bands=3, residual_bands_to_color=True)` (l_p^ap = 3);
- views augmentation: `RadianceField(view_dependent=False)`;
- ablations: identical augmentation `RadianceField()`, smaller network `RadianceField(num_layers=4, skip_layer=None)`.

Presets with the paper's values, so a config need not restate them: `PointsAugmentation` and `ViewsAugmentation`
(name, field, L_ap / L_av weight 0.1), and every augmentation's default mask, `PatchReprojectionMask()` (k = 5,
e_tau = 0.1, Sec. 4.2 and the supplement).

On grids (Simple-RF, arXiv 2404.19015, and its release) the authors changed the augmentation: a lower-capacity
density (`KPlanesField(density_features=...)`), a field empty near the camera (`min_ndc_z`) and a mass-concentration
loss on its ray weights (`concentration_weight`, `losses.mass_concentration_loss`).

A new augmentation plugs in from YAML by `class_path`: any `Field` (an MLP, a grid, a user's own), or a subclass of
`Augmentation` that overrides `render`.
"""

from __future__ import annotations

from typing import Literal

from torch import nn

from simplenerf.method.reliability import PatchReprojectionMask, ReliabilityMask
from simplenerf.model.fields import Field, RadianceField
from simplenerf.model.nerf import NeRF, NeRFOutputs
from simplenerf.model.rendering import RenderOutputs


class Augmentation(nn.Module):
    """A simplified field supervising (and supervised by) the main model's depth where it is more reliable."""

    def __init__(
        self,
        name: str,
        field: Field,
        mask: ReliabilityMask | None = None,
        depth_weight: float = 0.1,
        stage: Literal["coarse", "fine"] = "coarse",
        min_ndc_z: float | None = None,
        concentration_weight: float | None = None,
        concentration_bins: int = 5,
    ) -> None:
        """
        Args:
            name: name of its masked depth term (`points` -> L_ap, `views` -> L_av; `method.objective`).
            field: the simplified field (any `Field`), evaluated at the main model's samples.
            mask: decides per ray which of the two depths supervises the other; null: the paper's
                `PatchReprojectionMask()` (k = 5, e_tau = 0.1). (`reliability.TrustAll` is "no mask".)
            depth_weight: lambda_3 / lambda_4, weight of the masked depth loss (a warm-up schedule may override it).
            stage: evaluated at the main model's coarse samples and tied to the coarse depth (the paper), or at the
                fine samples and tied to the fine depth (the "w/o coarse-fine consistency" ablation adds those).
            min_ndc_z: the augmentation is empty in front of this NDC z (`rendering.cut_near`; Simple-TensoRF:
                -0.5); None: no cut.
            concentration_weight: weight of the mass-concentration loss on this augmentation's ray weights, the term
                `<name>_concentration` of the objective (a schedule may change it; Simple-TensoRF: 0.01 from 20% of
                the steps); None: no such term.
            concentration_bins: groups of samples the loss sums the weights in (Simple-RF: 5).
        """
        super().__init__()
        self.name, self.field, self.depth_weight, self.stage = name, field, depth_weight, stage
        self.mask = mask if mask is not None else PatchReprojectionMask()
        self.min_ndc_z, self.concentration_weight, self.concentration_bins = (min_ndc_z, concentration_weight,
                                                                             concentration_bins)

    def render(self, nerf: NeRF, main: NeRFOutputs, randomized: bool) -> RenderOutputs:
        """Renders the augmentation along the rays of `main`, at the main model's samples of its stage."""
        return nerf.render(self.field, main.samples(self.stage), randomized, min_ndc_z=self.min_ndc_z)

    def main_output(self, main: NeRFOutputs) -> RenderOutputs:
        """The main model's render this augmentation is tied to."""
        return main.coarse if self.stage == "coarse" else main.fine


class PointsAugmentation(Augmentation):
    """The paper's points augmentation (Sec. 4.1, L_ap): by default the paper's MLP whose density sees gamma(p, 0, 3)
    only, the other bands going to the colour branch."""

    def __init__(self, name: str = "points", field: Field | None = None, **kwargs) -> None:
        """
        Args:
            name: name of its masked depth term (L_ap).
            field: the simplified field; null: `RadianceField(density_bands=3, residual_bands_to_color=True)`.
            kwargs: `mask`, `depth_weight` (lambda_3), `stage`, `min_ndc_z`, `concentration_*`: as in `Augmentation`.
        """
        field = field if field is not None else RadianceField(density_bands=3, residual_bands_to_color=True)
        super().__init__(name, field, **kwargs)


class ViewsAugmentation(Augmentation):
    """The paper's views augmentation (Sec. 4.1, L_av): by default the paper's MLP without view directions."""

    def __init__(self, name: str = "views", field: Field | None = None, **kwargs) -> None:
        """
        Args:
            name: name of its masked depth term (L_av).
            field: the simplified field; null: `RadianceField(view_dependent=False)`.
            kwargs: `mask`, `depth_weight` (lambda_4), `stage`, `min_ndc_z`, `concentration_*`: as in `Augmentation`.
        """
        super().__init__(name, field if field is not None else RadianceField(view_dependent=False), **kwargs)
