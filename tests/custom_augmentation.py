"""A user's own augmentation, defined outside the package and plugged in from YAML by class_path (see the README).

`LowPassPointsAugmentation` builds its own field: a points augmentation whose colour branch also loses the bands the
density trunk loses, i.e. a field of gamma(p, 0, l) only.
"""

from __future__ import annotations

from simplenerf.method.augmentations import Augmentation
from simplenerf.method.reliability import PatchReprojectionMask
from simplenerf.model.fields import RadianceField


class LowPassPointsAugmentation(Augmentation):
    """A coarse field that sees only the lowest `bands` positional-encoding bands, for density and colour."""

    def __init__(self, bands: int = 2, width: int = 64, num_layers: int = 4, depth_weight: float = 0.1) -> None:
        """
        Args:
            bands: positional-encoding bands the field sees.
            width: trunk width.
            num_layers: trunk layers.
            depth_weight: weight of its masked depth loss.
        """
        field = RadianceField(density_bands=bands, residual_bands_to_color=False, width=width, num_layers=num_layers,
                              skip_layer=None)
        super().__init__("lowpass", field, PatchReprojectionMask(), depth_weight=depth_weight)
