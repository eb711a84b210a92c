"""LPIPS v0.1 with the AlexNet trunk, built from plain torch.nn so that torchvision is not needed.

The network reproduces the reference `lpips` package (Zhang et al. 2018, version 0.1, net='alex'):
a fixed scaling layer, the five ReLU taps of torchvision's AlexNet `features`, channel-wise unit normalisation,
squared feature differences weighted by learned 1x1 "linear" heads, spatial averaging and a sum over taps.

Weights come from two places. The AlexNet trunk (ImageNet weights, torchvision layout) is looked up in this order:
an explicit path, the `SIMPLENERF_LPIPS_WEIGHTS` environment variable, the torch hub cache file
`alexnet-owt-7be5be79.pth`, and finally (only with `allow_download=True`) the torchvision download URL. A path may be
a torchvision-layout `.pth` state dict or an `.npz` holding `features.N.{weight,bias}` (and optionally
`lpips_linK.weight`). The linear heads are read from the installed `lpips` package's `weights/v0.1/alex.pth`; the
package itself is never imported because its `__init__` imports torchvision. If that file is absent, heads stored in
the `.npz` are used instead.
"""

from __future__ import annotations

import importlib.util
import os
import socket
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from torch import nn

WEIGHTS_ENV = "SIMPLENERF_LPIPS_WEIGHTS"
ALEXNET_FILENAME = "alexnet-owt-7be5be79.pth"
ALEXNET_URL = f"https://download.pytorch.org/models/{ALEXNET_FILENAME}"
# An offline machine should fail within seconds rather than wait for the OS-level TCP timeout.
DOWNLOAD_TIMEOUT_S = 10.0

# Indices of the convolutions in torchvision's `AlexNet.features`; state dict keys depend on them.
_CONV_INDICES = (0, 3, 6, 8, 10)
# LPIPS taps the output of the ReLU that follows each convolution.
_TAP_INDICES = (1, 4, 7, 9, 11)
_TAP_CHANNELS = (64, 192, 384, 256, 256)
# Constants of the LPIPS ScalingLayer: they map [-1, 1] inputs to ImageNet-normalised ones.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_NORM_EPS = 1e-10
# Smallest side for which both max-pools of the trunk still see a 3x3 input.
MIN_IMAGE_SIZE = 31


class LPIPSWeightsNotFound(RuntimeError):
    """Raised when the AlexNet trunk or the LPIPS linear heads cannot be located."""


def _hub_cache_file() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILENAME


def _missing_message(reason: str) -> str:
    return (
        f"{reason} LPIPS needs the ImageNet AlexNet weights in torchvision layout ({ALEXNET_FILENAME}). Supply them "
        f"with the config option `--evaluation.lpips_weights PATH` (a torchvision .pth state dict or an .npz with "
        f"features.N.weight/bias keys), or set the environment variable {WEIGHTS_ENV}=PATH, or place the file at "
        f"{_hub_cache_file()} (the torch hub cache; it can be fetched from {ALEXNET_URL}), or disable LPIPS "
        f"(e.g. `--evaluation.lpips_weights none`) to skip the metric."
    )


def _lpips_package_heads_file() -> Path | None:
    """Path of `weights/v0.1/alex.pth` of the installed `lpips` package, found without importing it."""
    try:
        spec = importlib.util.find_spec("lpips")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(next(iter(spec.submodule_search_locations))) / "weights" / "v0.1" / "alex.pth"
    return path if path.is_file() else None


def _read_arrays(path: Path) -> dict[str, torch.Tensor]:
    """All tensors of a `.npz` archive or a `.pth` state dict, on the CPU."""
    if path.suffix == ".npz":
        with np.load(path) as archive:
            return {key: torch.from_numpy(archive[key].copy()) for key in archive.files}
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, Mapping):
        raise LPIPSWeightsNotFound(_missing_message(f"{path} does not hold a state dict."))
    return dict(state)


def _download_trunk() -> dict[str, torch.Tensor]:
    previous = socket.getdefaulttimeout()
    socket.setdefaulttimeout(DOWNLOAD_TIMEOUT_S)
    try:
        return dict(torch.hub.load_state_dict_from_url(ALEXNET_URL, map_location="cpu", progress=False))
    except Exception as err:  # any network or IO failure means the same thing to the caller
        raise LPIPSWeightsNotFound(_missing_message(f"Downloading {ALEXNET_URL} failed ({err!r}).")) from err
    finally:
        socket.setdefaulttimeout(previous)


def _resolve_trunk(path: str | os.PathLike[str] | None, allow_download: bool) -> dict[str, torch.Tensor]:
    """Arrays holding the trunk, from the first available source in the documented priority order."""
    # An explicitly named file that is missing is an error rather than a reason to fall back, so that a typo
    # cannot silently switch to different weights.
    if path is not None:
        explicit = Path(path).expanduser()
        if not explicit.is_file():
            what = "is a folder, not a file" if explicit.is_dir() else "does not exist"
            raise LPIPSWeightsNotFound(_missing_message(f"LPIPS weights file {explicit} {what}."))
        return _read_arrays(explicit)
    env_path = os.environ.get(WEIGHTS_ENV)
    if env_path:
        from_env = Path(env_path).expanduser()
        if not from_env.is_file():
            raise LPIPSWeightsNotFound(_missing_message(f"{WEIGHTS_ENV}={env_path} does not name an existing file."))
        return _read_arrays(from_env)
    cached = _hub_cache_file()
    if cached.is_file():
        return _read_arrays(cached)
    if allow_download:
        return _download_trunk()
    raise LPIPSWeightsNotFound(_missing_message("No AlexNet weights were found and downloading is disabled."))


def _resolve_heads(trunk_arrays: Mapping[str, torch.Tensor]) -> list[torch.Tensor]:
    """The five v0.1 linear-head weights, [1, C, 1, 1] each."""
    package_file = _lpips_package_heads_file()
    if package_file is not None:
        state = torch.load(package_file, map_location="cpu", weights_only=True)
        return [state[f"lin{k}.model.1.weight"] for k in range(len(_TAP_INDICES))]
    keys = [f"lpips_lin{k}.weight" for k in range(len(_TAP_INDICES))]
    if all(key in trunk_arrays for key in keys):
        return [trunk_arrays[key] for key in keys]
    raise LPIPSWeightsNotFound(
        "The LPIPS v0.1 linear heads were not found: the `lpips` package (weights/v0.1/alex.pth) is not installed "
        "and the weights file has no lpips_lin0..4.weight arrays. Install `lpips` without dependencies, supply an "
        f".npz that contains the heads via `--evaluation.lpips_weights PATH` or {WEIGHTS_ENV}, or disable LPIPS."
    )


def _alexnet_features() -> nn.Sequential:
    # Non-inplace ReLUs keep each tapped activation intact while later layers run.
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(384, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(256, 256, kernel_size=3, padding=1),
        nn.ReLU(),
    )


class LPIPS(nn.Module):
    """LPIPS v0.1 distance with the AlexNet backbone; frozen and in eval mode.

    Construct it with `LPIPS.from_weights(...)`; a bare `LPIPS()` has random weights.
    """

    def __init__(self) -> None:
        super().__init__()
        self.features = _alexnet_features()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in _TAP_CHANNELS)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def from_weights(cls, path: str | os.PathLike[str] | None = None, allow_download: bool = False) -> LPIPS:
        """Build the network with pretrained weights.

        Args:
            path: a torchvision-layout AlexNet `.pth` state dict or an `.npz` with `features.N.{weight,bias}` (and
                optionally `lpips_lin{0..4}.weight`). None falls back to `SIMPLENERF_LPIPS_WEIGHTS`, then to the
                torch hub cache, then (if allowed) to a download.
            allow_download: whether fetching the trunk from the torchvision URL is permitted.

        Raises:
            LPIPSWeightsNotFound: no weights could be located; the message says how to supply them.
        """
        arrays = _resolve_trunk(path, allow_download)
        net = cls()
        net.load_arrays(arrays, _resolve_heads(arrays))
        return net

    def load_arrays(self, trunk: Mapping[str, torch.Tensor], heads: list[torch.Tensor]) -> None:
        """Copy trunk weights (torchvision `features.N.*` keys; other keys are ignored) and the five heads."""
        with torch.no_grad():
            for index in _CONV_INDICES:
                conv = self.features[index]
                for name in ("weight", "bias"):
                    key = f"features.{index}.{name}"
                    if key not in trunk:
                        raise LPIPSWeightsNotFound(_missing_message(f"The weights file lacks the array {key}."))
                    getattr(conv, name).copy_(torch.as_tensor(trunk[key]).reshape(getattr(conv, name).shape))
            for lin, head in zip(self.lins, heads, strict=True):
                lin.weight.copy_(torch.as_tensor(head).reshape(lin.weight.shape))

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """LPIPS distance per image.

        Args:
            pred: [B, 3, H, W] RGB in [0, 1] (mapped to the [-1, 1] range LPIPS expects here); H, W >= 31.
            target: [B, 3, H, W] RGB in [0, 1].

        Returns:
            [B] distances, in the dtype and on the device of the network's parameters.
        """
        if min(pred.shape[-2:]) < MIN_IMAGE_SIZE:
            raise ValueError(f"LPIPS-alex needs images of at least {MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE}, got {pred.shape}")
        reference = self.shift
        x = torch.cat([pred, target]).to(device=reference.device, dtype=reference.dtype)
        x = ((x * 2.0 - 1.0) - self.shift) / self.scale
        batch = pred.shape[0]
        total = x.new_zeros(batch)
        taps = iter(self.lins)
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index not in _TAP_INDICES:
                continue
            unit = x / (torch.sqrt(torch.sum(x * x, dim=1, keepdim=True)) + _NORM_EPS)
            diff = (unit[:batch] - unit[batch:]) ** 2
            total = total + next(taps)(diff).mean(dim=(1, 2, 3))
        return total
