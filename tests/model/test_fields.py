import pytest
import torch

from simplenerf.model.encodings import positional_encoding
from simplenerf.model.fields import Field, RadianceField
from simplenerf.model.samples import Samples


def encodings(rays: int = 4, samples: int = 5):
    p, v = torch.randn(rays, samples, 3), torch.nn.functional.normalize(torch.randn(rays, 3), dim=-1)
    return p, positional_encoding(p, 10), positional_encoding(v, 4)


def at(p_enc: torch.Tensor, v_enc: torch.Tensor) -> Samples:
    """Samples whose cached encodings are the given ones (so a test can perturb an encoding directly)."""
    r, s = p_enc.shape[:2]
    zeros = torch.zeros(r, s)
    samples = Samples(zeros, zeros, zeros, p_enc[..., :3], v_enc[..., :3])
    samples._encodings.update(positions=p_enc, directions=v_enc)
    return samples


def test_samples_encode_once_and_share_lower_bands():
    p, p_enc, v_enc = encodings()
    samples = Samples(*(torch.zeros(4, 5),) * 3, p, v_enc[..., :3])
    full = samples.encoded_positions(10)
    assert torch.equal(full, p_enc)
    low = samples.encoded_positions(3)
    assert torch.equal(low, positional_encoding(p, 3)) and low.data_ptr() == full.data_ptr()  # a view, no new work
    assert torch.equal(samples.encoded_directions(4), v_enc)


def test_fields_are_called_with_samples():
    _, p_enc, v_enc = encodings()
    field = RadianceField(num_layers=2, width=8, skip_layer=None)
    assert isinstance(field, Field) and set(field.parameter_groups()) == {"mlp"}
    assert field.regularizers() == {}
    out = field(at(p_enc, v_enc))
    assert out.raw_density.shape == (4, 5) and out.rgb.shape == (4, 5, 3)


def test_main_field_layout_of_the_release():
    field = RadianceField()
    assert [layer.in_features for layer in field.trunk] == [63, 256, 256, 256, 256, 256 + 63, 256, 256]
    assert field.color[0].in_features == 283
    _, p_enc, v_enc = encodings()
    out = field(at(p_enc, v_enc))
    assert out.raw_density.shape == (4, 5) and out.rgb.shape == (4, 5, 3)
    assert bool(((out.rgb > 0) & (out.rgb < 1)).all())


def test_points_augmentation_sees_only_low_bands_in_its_trunk():
    field = RadianceField(density_bands=3, residual_bands_to_color=True)
    assert field.trunk[0].in_features == 21 and field.trunk[5].in_features == 256 + 21
    assert field.color[0].in_features == 325
    p, p_enc, v_enc = encodings()
    # Changing only the high bands leaves density unchanged but changes colour.
    perturbed = p_enc.clone()
    perturbed[..., 21:] += 1.0
    a, b = field(at(p_enc, v_enc)), field(at(perturbed, v_enc))
    assert torch.equal(a.raw_density, b.raw_density)
    assert not torch.allclose(a.rgb, b.rgb)


def test_views_augmentation_ignores_directions():
    field = RadianceField(view_dependent=False)
    assert field.output.out_features == 4
    _, p_enc, v_enc = encodings()
    a, b = field(at(p_enc, v_enc)), field(at(p_enc, -v_enc))
    assert torch.equal(a.rgb, b.rgb) and torch.equal(a.raw_density, b.raw_density)


def test_main_field_colour_depends_on_direction():
    _, p_enc, v_enc = encodings()
    field = RadianceField()
    assert not torch.allclose(field(at(p_enc, v_enc)).rgb, field(at(p_enc, -v_enc)).rgb)


def test_invalid_configurations_are_rejected():
    with pytest.raises(ValueError):
        RadianceField(density_bands=11)
    with pytest.raises(ValueError):
        RadianceField(num_layers=4, skip_layer=5)
    with pytest.raises(ValueError):
        RadianceField(view_dependent=False, density_bands=3, residual_bands_to_color=True)



@pytest.mark.parametrize(
    "kwargs", [{}, {"view_dependent": False}, {"density_bands": 3, "residual_bands_to_color": True}]
)
def test_density_only_samples_skip_the_colour_branch(kwargs):
    """Where no loss reads colour (`Samples.color` False): the same raw density, no rgb, and no gradient reaches
    the colour branch."""
    torch.manual_seed(0)
    _, p_enc, v_enc = encodings()
    field = RadianceField(num_layers=3, width=16, skip_layer=1, color_width=8, **kwargs)
    full = field(at(p_enc, v_enc))
    samples = at(p_enc, v_enc)
    samples.color = False
    only = field(samples)
    assert only.rgb is None and torch.allclose(only.raw_density, full.raw_density, rtol=1e-6, atol=1e-7)
    only.raw_density.sum().backward()
    # the colour weights: the colour head's, or the output layer's rows after density's (a leaf's rows: a slice of
    # the weight itself would be a non-leaf without a gradient)
    weight, rows = (field.color[0].weight, slice(None)) if field.view_dependent else (field.output.weight, slice(1, 4))
    assert weight.grad is None or not weight.grad[rows].any()
    assert field.trunk[0].weight.grad.abs().sum() > 0
