"""The validation pictures: RGB, depth, accumulation and error of the validation view (the callback that logs and
saves them, with SimpleNeRF's reliability masks on the first train view: `simplenerf.run.callbacks.ValidationRenders`).
"""

from __future__ import annotations

import numpy as np
import torch

from simplenerf.model.nerf import FrameRender
from simplenerf.viz.pictures import (
    colorize_depth,
    colorize_error,
    grey_picture,
    to_uint8,
)

KINDS = ("rgb", "depth", "accumulation", "error")


def error_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel |pred - target| averaged over channels: [H, W] from images [H, W, 3]."""
    assert pred.shape == target.shape and pred.shape[-1] == 3, f"images differ: {pred.shape} vs {target.shape}"
    return (pred - target.to(pred)).abs().mean(dim=-1)


def render_pictures(pred: FrameRender, target: torch.Tensor, max_error: float) -> dict[str, np.ndarray]:
    """The pictures of one rendered frame, by kind (`KINDS`).

    Args:
        pred: rgb [H, W, 3], depth [H, W], accumulation [H, W] (the module's `render_frame`).
        target: [H, W, 3] ground truth in [0, 1].
        max_error: error shown at the top of the error colour map.
    """
    as_numpy = {k: x.detach().float().cpu().numpy() for k, x in (("rgb", pred.rgb), ("depth", pred.depth),
                                                                   ("accumulation", pred.accumulation))}
    error = error_map(pred.rgb.detach(), target).float().cpu().numpy()
    return {
        "rgb": to_uint8(as_numpy["rgb"]),
        "depth": colorize_depth(as_numpy["depth"]),  # the frame's own percentiles: contrast within one picture
        "accumulation": grey_picture(as_numpy["accumulation"]),
        "error": colorize_error(error, max_error),
    }
