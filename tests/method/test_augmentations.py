"""The paper's presets: the points and views augmentations and the mask every augmentation takes by default."""

from __future__ import annotations

import torch

from simplenerf.method.augmentations import Augmentation, PointsAugmentation, ViewsAugmentation
from simplenerf.method.reliability import PatchReprojectionMask, TrustAll
from simplenerf.model.fields import RadianceField


def same_field(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    """Same architecture and, built after the same seed, the same weights."""
    return str(a) == str(b) and all(torch.equal(x, y) for x, y in zip(a.state_dict().values(),
                                                                        b.state_dict().values(), strict=True))


def test_presets_are_the_papers_augmentations_and_mask():
    torch.manual_seed(0)
    points, views = PointsAugmentation(), ViewsAugmentation()
    torch.manual_seed(0)
    paper_points = RadianceField(density_bands=3, residual_bands_to_color=True)
    paper_views = RadianceField(view_dependent=False)
    assert same_field(points.field, paper_points) and same_field(views.field, paper_views)
    assert (points.name, views.name, points.depth_weight, views.depth_weight) == ("points", "views", 0.1, 0.1)
    assert points.stage == views.stage == "coarse"
    for aug in (points, views, Augmentation("x", RadianceField(num_layers=2, width=8, skip_layer=None))):
        assert type(aug.mask) is PatchReprojectionMask
        assert (aug.mask.patch_size, aug.mask.error_threshold, aug.mask.require_in_front) == (5, 0.1, True)
    assert points.mask is not views.mask and points.field is not PointsAugmentation().field  # nothing shared
    assert isinstance(PointsAugmentation(mask=TrustAll()).mask, TrustAll)  # a preset's parts can still be given
