import torch

from simplenerf.model.samplers import hierarchical_samples, sample_pdf, stratified_samples


def test_stratified_deterministic_is_linspace():
    t = stratified_samples(2, 5, perturb=False, like=torch.zeros(1))
    assert torch.allclose(t, torch.tensor([[0.0, 0.25, 0.5, 0.75, 1.0]] * 2))


def test_stratified_jitter_stays_in_its_stratum():
    torch.manual_seed(0)
    t = stratified_samples(1000, 5, perturb=True, like=torch.zeros(1))
    lower = torch.tensor([0.0, 0.125, 0.375, 0.625, 0.875])
    upper = torch.tensor([0.125, 0.375, 0.625, 0.875, 1.0])
    assert bool(((t >= lower) & (t <= upper)).all())
    assert t.std(0).min() > 0.01


def test_pdf_samples_fall_in_the_only_weighted_bin():
    bins = torch.tensor([[0.0, 0.1, 0.2, 0.3, 0.4]])
    weights = torch.tensor([[0.0, 0.0, 1.0, 0.0]])
    s = sample_pdf(bins, weights, 16, deterministic=True)
    assert bool(((s >= 0.2) & (s <= 0.3)).all())
    assert torch.allclose(s, torch.linspace(0.2, 0.3, 16)[None], atol=1e-6)


def test_hierarchical_keeps_coarse_samples_sorted_and_detached():
    t = stratified_samples(3, 8, perturb=False, like=torch.zeros(1))
    w = torch.rand(3, 8, requires_grad=True)
    fine = hierarchical_samples(t, w, 16, deterministic=True)
    assert fine.shape == (3, 24)
    assert bool((fine[:, 1:] >= fine[:, :-1]).all())
    assert all(bool(torch.isin(t[i], fine[i]).all()) for i in range(3))
    assert not fine.requires_grad
