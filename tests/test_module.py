"""The LightningModule's loss composition (paper Sec. 4.4) on real data-module batches."""

import pytest
import torch

from simplenerf.data.synthetic import SyntheticDataModule
from simplenerf.module import SimpleNeRF
from simplenerf.nerf import NeRF


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("module")
    dm = SyntheticDataModule(root=str(tmp / "data"), height=240, width=320, n_frames=8, n_views=2, rays_per_batch=32,
                             sparse_rays_per_batch=16, sparse_depth_cache=str(tmp / "cache"))
    dm.setup("fit")
    return next(iter(dm.train_dataloader()))


def module(**weights) -> SimpleNeRF:
    torch.manual_seed(0)
    return SimpleNeRF(NeRF(num_coarse=8, num_fine=8, num_layers=2, width=16, skip_layer=1), **weights)


def test_loss_is_the_weighted_sum_of_its_terms(batch, monkeypatch):
    model = module(color_weight=1.0, sparse_depth_weight=0.1)
    logged = {}
    monkeypatch.setattr(model, "log_dict", lambda values, **kw: logged.update(values))
    monkeypatch.setattr(model, "log", lambda *a, **kw: None)
    loss = model.training_step(batch, 0)
    expected = logged["train/loss_color"] + 0.1 * logged["train/loss_sparse_depth"]
    assert torch.allclose(loss, expected)
    assert logged["train/loss_sparse_depth"] > 0


def test_sparse_depth_loss_trains_fine_not_coarse(batch, monkeypatch):
    model = module(color_weight=0.0, sparse_depth_weight=1.0)
    monkeypatch.setattr(model, "log_dict", lambda *a, **kw: None)
    monkeypatch.setattr(model, "log", lambda *a, **kw: None)
    model.training_step(batch, 0).backward()
    assert model.nerf.fine.trunk[0].weight.grad.abs().sum() > 0
    coarse_grad = model.nerf.coarse.trunk[0].weight.grad
    assert coarse_grad is None or coarse_grad.abs().sum() == 0


def test_without_sparse_rays_only_colour_counts(batch, monkeypatch):
    model = module()
    logged = {}
    monkeypatch.setattr(model, "log_dict", lambda values, **kw: logged.update(values))
    monkeypatch.setattr(model, "log", lambda *a, **kw: None)
    plain = {k: v for k, v in batch.items() if not k.startswith("sparse_")}
    loss = model.training_step(plain, 0)
    assert "train/loss_sparse_depth" not in logged and torch.allclose(loss, logged["train/loss_color"])
