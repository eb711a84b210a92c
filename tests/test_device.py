"""GPU readiness without a GPU: one training step of configs/llff.yaml (shrunk: 64 + 32 rays, 2x16 MLPs, 8 + 8
samples; the points and views augmentations, their reliability masks, L_cfc and the sparse depth all on) with the
module and the batch on a device other than the CPU (tests/device_check.py), so that a tensor made on the CPU in
the middle of a step (a mask, an index, a view's image) fails here and not on a user's first GPU fit."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
import yaml
from lightning.fabric.utilities.apply_func import move_data_to_device

from simplenerf.run.cli import make_cli
from simplenerf.synthetic.generate import make_synthetic_scene
from tests.conftest import REPO
from tests.device_check import DEVICE, CpuTensorOnDevice, OnDevice, on_device
from tests.run.test_cli import shrink


@pytest.fixture(scope="module")
def paper_step(tmp_path_factory):
    """configs/llff.yaml, shrunk, on a 120x160 synthetic scene (SfM finds its points), and one training batch."""
    tmp = tmp_path_factory.mktemp("device")
    scene = make_synthetic_scene(tmp / "scene", height=120, width=160, n_frames=12)
    model = yaml.safe_load((REPO / "configs" / "llff.yaml").read_text())["model"]
    small = tmp / "small.yaml"
    small.write_text(yaml.safe_dump({"model": {k: shrink(model[k]) for k in ("nerf", "augmentations")}}))
    cli = make_cli(["--config", str(REPO / "configs" / "llff.yaml"), "--config", str(small),
                    "--data.init_args.scene_dir", str(scene), "--data.init_args.factor", "1",
                    "--data.init_args.rays_per_batch", "64", "--data.init_args.sparse_rays_per_batch", "32",
                    "--model.rays_per_backward", "48", "--data.init_args.sparse_depth_cache", str(tmp / "cache"),
                    "--trainer.logger", "false"], run=False)
    cli.datamodule.setup("fit")
    return cli.model, cli.datamodule


def training_step_on_device(model, datamodule) -> tuple[torch.Tensor, dict]:
    """The module's own training_step (zero_grad, the parts' backward, optimiser and schedule steps, logging) with
    the module, its train views and the batch on DEVICE, as Lightning would run it on a GPU; returns the loss and
    what it logged."""
    batch = next(iter(datamodule.train_dataloader()))
    logged: dict = {}
    with on_device():
        model.to(DEVICE)
        model.set_train_views(datamodule.train_views)
        model.on_fit_start()  # the train views to the module's device
        on = move_data_to_device(batch, DEVICE)  # Lightning's transfer_batch_to_device
        optim = model.configure_optimizers()
        optimizer, schedule = optim["optimizer"], optim["lr_scheduler"]["scheduler"]
        model._trainer = SimpleNamespace(strategy=None)  # one process: no DDP sync
        model.optimizers, model.lr_schedulers = (lambda: optimizer), (lambda: schedule)
        model.manual_backward = torch.Tensor.backward
        model.log_dict = lambda values, **kw: logged.update(values)
        model.log = lambda *a, **kw: None
        loss = model.training_step(on, 0)
        assert all(isinstance(p, OnDevice) and p.device == DEVICE for p in model.parameters())
        grads = [p.grad for p in model.parameters() if p.grad is not None]
        assert grads and all(isinstance(g, OnDevice) for g in grads)
    return loss, logged


def test_a_step_of_the_paper_config_stays_on_the_device(paper_step):
    model, datamodule = paper_step
    loss, logged = training_step_on_device(model, datamodule)
    assert isinstance(loss, OnDevice) and loss.device == DEVICE and torch.isfinite(loss._cpu)
    # every term of the paper's loss and every reliability mask took part
    terms = {"color", "sparse_depth", "points", "views", "cfc"}
    assert {k.removeprefix("train/loss_") for k in logged if k.startswith("train/loss_")} == terms
    assert {f"train/mask_{t}/{s}" for t in ("points", "views", "cfc") for s in ("plus", "minus", "zero")} <= set(logged)


def test_the_check_catches_a_cpu_tensor_made_mid_step(paper_step, monkeypatch):
    """The check can fail: a reliability mask built from a CPU tensor (as `torch.ones(n)` without a device would)."""
    import simplenerf.method.reliability as reliability

    def ternary_mask(error_main, error_other, threshold):  # the real mask, its +1 made as torch.ones(n) would be
        mask = original(error_main, error_other, threshold)
        return torch.where(mask > 0, torch.ones(mask.shape), mask)

    original = reliability.ternary_mask
    monkeypatch.setattr(reliability, "ternary_mask", ternary_mask)
    with pytest.raises(CpuTensorOnDevice, match=r"aten.where.self: a tensor of shape \(\d+,\) made on the CPU meets"):
        training_step_on_device(*paper_step)
