import math

import pytest
import torch

from simplenerf.model.encodings import band_slice, encoded_dim, positional_encoding


def test_gamma_hand_computed():
    x = torch.tensor([[0.5]])
    expected = [0.5, math.sin(0.5), math.cos(0.5), math.sin(1.0), math.cos(1.0), math.sin(2.0), math.cos(2.0)]
    assert torch.allclose(positional_encoding(x, 3), torch.tensor([expected]))


def test_gamma_dims_of_the_paper():
    p = torch.rand(5, 7, 3)
    assert positional_encoding(p, 10).shape == (5, 7, 63) == (5, 7, encoded_dim(3, 10))
    assert positional_encoding(torch.rand(5, 3), 4).shape[-1] == 27


def test_band_slices_are_the_lower_and_residual_encodings():
    p = torch.randn(4, 3)
    full = positional_encoding(p, 10)
    low = full[:, band_slice(3, 0, 3, include_input=True)]
    assert low.shape[-1] == 21
    assert torch.equal(low, positional_encoding(p, 3))
    high = full[:, band_slice(3, 3, 10, include_input=False)]
    assert high.shape[-1] == 42
    assert torch.allclose(high[:, :3], torch.sin(8.0 * p))  # first residual block: sin(2^3 p)


def test_band_slice_rejects_identity_without_band_zero():
    with pytest.raises(ValueError):
        band_slice(3, 2, 5, include_input=True)
