import torch

from simplenerf.model.rendering import composite, compute_weights, cut_near, deltas, density


def test_transmittance_and_weights_hand_computed():
    # alphas 0, .3, .8, .8 -> T = 1, 1, .7, .14 and w = alpha T.
    alpha = torch.tensor([[0.0, 0.3, 0.8, 0.8]])
    sigma = -torch.log(1 - alpha)
    w = compute_weights(sigma, torch.ones_like(sigma))
    expected_t = torch.tensor([[1.0, 1.0, 0.7, 0.14]])
    assert torch.allclose(w, alpha * expected_t, atol=1e-6)
    assert torch.allclose(w, torch.tensor([[0.0, 0.3, 0.56, 0.112]]), atol=1e-6)


def test_last_delta_runs_to_ndc_infinity():
    t = torch.tensor([[0.0, 0.25, 0.5, 0.9]])
    d = torch.tensor([[0.0, 0.0, 2.0]])
    assert torch.allclose(deltas(t, d), torch.tensor([[0.5, 0.5, 0.8, 0.2]]))


def test_depth_is_normalised_by_accumulation():
    w = torch.tensor([[0.0, 0.2, 0.2, 0.0]])
    t_metric = torch.tensor([[1.0, 2.0, 4.0, 8.0]])
    rgb = torch.ones(1, 4, 3)
    out = composite(w, rgb, t_metric)
    assert torch.allclose(out.depth, torch.tensor([1.2 / (0.4 + 1e-6)]))
    assert torch.allclose(out.accumulation, torch.tensor([0.4]))
    assert torch.allclose(out.rgb, torch.full((1, 3), 0.4))


def test_density_noise_only_when_asked():
    raw = torch.tensor([[-1.0, 0.5]])
    assert torch.equal(density(raw, 0.0), torch.tensor([[0.0, 0.5]]))
    torch.manual_seed(0)
    assert not torch.equal(density(raw.expand(1000, 2), 1.0)[:, 1], torch.full((1000,), 0.5))


def test_cut_near_empties_exactly_the_samples_in_front_of_the_cut():
    sigma = torch.tensor([[1.0, 2.0, 3.0, 4.0]], requires_grad=True)
    ndc_z = torch.tensor([[-1.0, -0.6, -0.5, 0.2]])
    cut = cut_near(sigma, ndc_z, -0.5)
    assert torch.equal(cut, torch.tensor([[0.0, 0.0, 3.0, 4.0]]))  # z = -0.5 itself is kept
    cut.sum().backward()
    assert torch.equal(sigma.grad, torch.tensor([[0.0, 0.0, 1.0, 1.0]]))  # no gradient in front of the cut
