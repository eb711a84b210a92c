"""Near-identical images: the same photo twice (a copied file, a re-encoded one) among the few views of a scene, which
structure from motion cannot place and a NeRF cannot learn depth from. A cheap check on thumbnails, for the train views
of a fit (`data.scene.SceneDataModule.check_inputs`) and process-data's photos."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

TOLERANCE = 2.0 / 255
"""Mean absolute difference (colours in [0, 1]) of two thumbnails under which the images count as the same: a photo
re-saved as JPEG differs by about 1/255; two views a step apart differ by several times this."""


def thumbnail(image: np.ndarray, side: int = 32) -> np.ndarray:
    """`image` ([H, W, C], uint8 or float in [0, 1]) as a float32 thumbnail of about `side` pixels along its shorter
    side, each pixel the mean of a block (so noise and re-encoding average out)."""
    image = np.asarray(image)
    image = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image.astype(np.float32)
    if image.ndim == 2:
        image = image[..., None]
    height, width = image.shape[:2]
    k = max(1, min(height, width) // side)
    h, w = height // k * k, width // k * k
    return image[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def near_duplicates(thumbnails: Sequence[np.ndarray], names: Sequence[str],
                    tolerance: float = TOLERANCE) -> list[tuple[str, str]]:
    """Pairs (by name, in order) of images whose thumbnails (`thumbnail`) differ by at most `tolerance` on average;
    thumbnails of different shapes are different images."""
    pairs = []
    for i in range(len(thumbnails)):
        for j in range(i + 1, len(thumbnails)):
            a, b = thumbnails[i], thumbnails[j]
            if a.shape == b.shape and float(np.abs(a - b).mean()) <= tolerance:
                pairs.append((names[i], names[j]))
    return pairs


def describe_duplicates(pairs: list[tuple[str, str]]) -> str:
    """`a and b, c and d` (at most 3 pairs, then how many more)."""
    listed = ", ".join(f"{a} and {b}" for a, b in pairs[:3])
    return listed + (f" (and {len(pairs) - 3} more pairs)" if len(pairs) > 3 else "")
