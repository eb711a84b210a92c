from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

from simplenerf.metrics.scores import psnr
from simplenerf.model.nerf import FrameRender
from simplenerf.run.callbacks import ValidationRenders
from simplenerf.viz.renders import (
    KINDS,
    colorize_error,
    error_map,
    grey_picture,
    render_pictures,
    to_uint8,
)

H, W = 6, 10


def inferno(levels: list[int]) -> np.ndarray:
    """RGB colours [len(levels), 3] of OpenCV's inferno map at 8-bit levels."""
    bgr = cv2.applyColorMap(np.array([levels], np.uint8), cv2.COLORMAP_INFERNO)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)[0]


def frame() -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """A prediction (grey 0.5, accumulation 0.25, depth 1..2) and a target off by 0.25 on the right half."""
    pred = FrameRender(rgb=torch.full((H, W, 3), 0.5), depth=torch.linspace(1.0, 2.0, H * W).reshape(H, W),
                       accumulation=torch.full((H, W), 0.25), coarse_depth=torch.ones(H, W))
    target = torch.full((H, W, 3), 0.5)
    target[:, W // 2 :] = 0.75
    return pred, target


def test_picture_helpers_exact():
    assert np.array_equal(to_uint8(np.array([-0.1, 0.0, 0.5, 1.0, 2.0])), [0, 0, 128, 255, 255])
    assert np.array_equal(grey_picture(np.array([[0.25]])), [[[64, 64, 64]]])
    pred, target = frame()
    err = error_map(pred.rgb, target)
    assert err.shape == (H, W) and torch.all(err[:, : W // 2] == 0)
    assert torch.allclose(err[:, W // 2 :], torch.tensor(0.25))
    picture = colorize_error(np.array([[0.0, 0.25, 0.5, 0.9]]), max_error=0.5)
    assert np.array_equal(picture[0], inferno([0, 128, 255, 255]))  # fixed range, clipped above max_error


def test_render_pictures():
    pred, target = frame()
    pictures = render_pictures(pred, target, max_error=0.5)
    assert list(pictures) == list(KINDS)
    for picture in pictures.values():
        assert picture.shape == (H, W, 3) and picture.dtype == np.uint8
    assert (pictures["rgb"] == 128).all() and (pictures["accumulation"] == 64).all()
    assert (pictures["error"][:, : W // 2] == inferno([0])[0]).all()
    assert (pictures["error"][:, W // 2 :] == inferno([128])[0]).all()
    # inverse depth coloured: the nearest pixel (depth 1, top left) is the warm end, the farthest the cold end
    assert not np.array_equal(pictures["depth"][0, 0], pictures["depth"][-1, -1])


class ImageLogger:
    def __init__(self) -> None:
        self.calls: list[dict] = []

    def log_image(self, **kwargs) -> None:
        self.calls.append(kwargs)


def fake_trainer(root, step: int, loggers: list, sanity: bool = False, zero: bool = True) -> SimpleNamespace:
    return SimpleNamespace(sanity_checking=sanity, global_step=step, default_root_dir=str(root), loggers=loggers,
                           is_global_zero=zero)


def validate(callback: ValidationRenders, trainer: SimpleNamespace) -> None:
    """One validation epoch of the single validation frame, as Lightning calls the hooks."""
    pred, target = frame()
    batch = SimpleNamespace(rgb=target.reshape(-1, 3), height=H, width=W, name="008", index=8)  # a `Frame`
    callback.on_validation_epoch_start(trainer, None)
    callback.on_validation_batch_end(trainer, None, pred, batch, 0)


def test_callback_logs_and_saves_the_pictures(tmp_path):
    logger = ImageLogger()
    validate(ValidationRenders(), fake_trainer(tmp_path, 250, [logger, object()]))  # a logger without images too
    names = sorted(p.name for p in (tmp_path / "val").iterdir())
    assert names == sorted(f"step000250_{kind}.png" for kind in KINDS)
    for kind in KINDS:
        assert cv2.imread(str(tmp_path / "val" / f"step000250_{kind}.png")).shape == (H, W, 3)
    pred, target = frame()
    expected_psnr = float(psnr(pred.rgb[None], target[None])[0])
    assert [c["key"] for c in logger.calls] == [f"val/render_{kind}" for kind in KINDS]
    assert all(c["step"] == 250 and len(c["images"]) == 1 for c in logger.calls)
    assert logger.calls[0]["caption"] == ["008 step 250"]
    assert logger.calls[3]["caption"] == [f"008 step 250 PSNR {expected_psnr:.2f} dB"]
    assert np.array_equal(logger.calls[1]["images"][0], cv2.cvtColor(
        cv2.imread(str(tmp_path / "val" / "step000250_depth.png")), cv2.COLOR_BGR2RGB))


def test_callback_skips_sanity_checks_and_honours_its_options(tmp_path):
    logger = ImageLogger()
    callback = ValidationRenders(every_n_validations=2)
    validate(callback, fake_trainer(tmp_path / "a", 0, [logger], sanity=True))
    for step in (10, 20, 30):  # validations 1, 2, 3: the 1st and the 3rd are drawn
        validate(callback, fake_trainer(tmp_path / "a", step, [logger]))
    assert sorted({p.name.split("_")[0] for p in (tmp_path / "a" / "val").iterdir()}) == ["step000010", "step000030"]
    assert len(logger.calls) == 8
    logger = ImageLogger()
    validate(ValidationRenders(save_to_disk=False), fake_trainer(tmp_path / "b", 5, [logger]))
    validate(ValidationRenders(log_images=False), fake_trainer(tmp_path / "c", 5, [logger]))
    validate(ValidationRenders(), fake_trainer(tmp_path / "d", 5, [], zero=False))  # not rank 0: no files
    assert len(logger.calls) == 4 and not (tmp_path / "b").exists() and not (tmp_path / "d").exists()
    assert len(list((tmp_path / "c" / "val").iterdir())) == 4
    with pytest.raises(ValueError, match="every_n_validations"):
        ValidationRenders(every_n_validations=0)


def test_every_run_gets_the_callback_configurable_from_the_cli():
    from tests.test_configs import CONFIG_DIR, parse

    assert parse(CONFIG_DIR / "demo.yaml").val_renders.every_n_validations == 1  # present without being configured
    configured = parse(CONFIG_DIR / "demo.yaml", "--val_renders.every_n_validations", "3")
    assert configured.val_renders.every_n_validations == 3
