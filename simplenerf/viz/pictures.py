"""Pictures: colour maps, 8-bit conversion (`to_uint8`, from `metrics.scores`), PNG writing and publishing to
loggers. Built on numpy and cv2.

Pictures are 8-bit RGB numpy arrays [H, W, 3], what both W&B and `write_png` take.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch

from simplenerf.metrics.scores import to_uint8  # the one 8-bit rule (also the metrics' quantisation); re-exported


def grey_picture(values: np.ndarray) -> np.ndarray:
    """[H, W] values in [0, 1] (e.g. accumulated opacity) as a grey RGB picture [H, W, 3]."""
    return np.repeat(to_uint8(values)[..., None], 3, axis=-1)


def inverse_depth_range(depth: np.ndarray) -> tuple[float, float]:
    """The 1st and 99th percentiles of a depth map's [H, W] inverse depth: `colorize_depth`'s default range, to give
    several maps one range (e.g. that of the exact depth)."""
    return _percentile_range(_inverse(depth))


def _inverse(depth: np.ndarray) -> np.ndarray:
    return 1.0 / np.maximum(depth, 1e-6)


def _percentile_range(inv: np.ndarray) -> tuple[float, float]:
    return float(np.percentile(inv, 1)), float(np.percentile(inv, 99))


def colorize_depth(depth: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """An 8-bit RGB picture [H, W, 3] of a depth map [H, W]: turbo colours of inverse depth (near = warm), from the
    1st to the 99th percentile of inverse depth unless `lo` / `hi` fix the range."""
    inv = _inverse(depth)
    if lo is None or hi is None:
        own_lo, own_hi = _percentile_range(inv)
        lo = own_lo if lo is None else lo
        hi = own_hi if hi is None else hi
    scaled = np.clip((inv - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return cv2.cvtColor(cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)


def colorize_error(error: np.ndarray, max_error: float) -> np.ndarray:
    """An error map [H, W] as an RGB picture [H, W, 3]: inferno colours, 0 black, `max_error` and above brightest.

    The range is fixed rather than per frame so that pictures of different steps can be compared."""
    scaled = to_uint8(error / max_error)
    return cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_INFERNO), cv2.COLOR_BGR2RGB)


def mask_picture(mask: torch.Tensor) -> np.ndarray:
    """8-bit RGB picture of a ternary reliability mask [H, W] as in the paper's supplement: black where the other
    (augmented or fine) depth is preferred (+1), white where the main depth is (-1), grey where neither is (0)."""
    grey = (127.5 * (1.0 - mask.float())).round().clamp(0, 255).to(torch.uint8).cpu().numpy()
    return np.repeat(grey[..., None], 3, axis=-1)


def write_png(path: Path, rgb: np.ndarray, jpeg_quality: int = 95) -> None:
    """Writes an RGB image [H, W, 3] (uint8, or float in [0, 1]): a PNG, or a JPEG of `jpeg_quality` where the path
    ends in .jpg (OpenCV picks the format by the extension)."""
    if rgb.dtype != np.uint8:
        rgb = to_uint8(rgb)
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if Path(path).suffix.lower() in (".jpg", ".jpeg") else []
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params):
        raise OSError(f"could not write {path}")


def write_mask_png(path: Path, mask: np.ndarray) -> None:
    """Writes a bool mask [H, W] as an 8-bit grey PNG: white (255) where True, black elsewhere."""
    if not cv2.imwrite(str(path), np.where(mask, 255, 0).astype(np.uint8)):
        raise OSError(f"could not write {path}")


def publish_picture(trainer: L.Trainer, key: str, picture: np.ndarray, file_name: str, caption: str | None = None,
                    log: bool = True, save: bool = True) -> None:
    """Sends a picture [H, W, 3] to every logger that takes images (W&B: `key`, at the trainer's step) and, on global
    rank 0, writes it to `<trainer.default_root_dir>/val/<file_name>`."""
    if log:
        for logger in trainer.loggers:
            log_image = getattr(logger, "log_image", None)  # Lightning's Logger has no image method; W&B's has
            if log_image is not None:
                extra = {} if caption is None else {"caption": [caption]}
                log_image(key=key, images=[picture], step=trainer.global_step, **extra)
    if save and trainer.is_global_zero:
        out = Path(trainer.default_root_dir) / "val"
        out.mkdir(parents=True, exist_ok=True)
        write_png(out / file_name, picture)
