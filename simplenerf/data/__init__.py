"""Scenes and what the model is fed: formats (LLFF, RealEstate-10K, the synthetic scene), splits, rays, batches.

`simplenerf.data.LLFFDataModule` and `simplenerf.data.RealEstateDataModule` are resolved on first use, so importing
the typed batches (`simplenerf.data.batches`) does not load the SfM machinery (pycolmap).
"""

from __future__ import annotations

import importlib

_MODULES = {"LLFFDataModule": "simplenerf.data.llff", "RealEstateDataModule": "simplenerf.data.realestate",
            "SceneDataModule": "simplenerf.data.scene"}
__all__ = list(_MODULES)


def __getattr__(name: str):
    if name in _MODULES:
        return getattr(importlib.import_module(_MODULES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
