"""The built-in synthetic scene as a data format: generated on first use (`simplenerf.synthetic.generate`), then read
as an LLFF-layout scene."""

from __future__ import annotations

from pathlib import Path

from jsonargparse.typing import PositiveInt

from simplenerf.data.llff import LLFFDataModule
from simplenerf.synthetic.generate import make_synthetic_scene


class SyntheticDataModule(LLFFDataModule):
    """The built-in synthetic scene as a data module: generated under `root` on first use, then read as LLFF.

    Its exact depth maps are the reference depth of `test` (depth MAE and SROCC). Every other argument is the
    `LLFFDataModule`'s.
    """

    def __init__(
        self, root: str = "data/synthetic", height: PositiveInt = 96, width: PositiveInt = 128,
        n_frames: PositiveInt = 20, scene_seed: int = 0, kind: str = "planes", **kwargs,
    ) -> None:
        """
        Args:
            root: folder of generated scenes; this one is <root>/seed{scene_seed}_{height}x{width}_{n_frames}
                (prefixed `objects_` for that kind).
            height: image height in pixels.
            width: image width in pixels.
            n_frames: number of frames (every test_every-th is a test frame).
            scene_seed: seed of the scene's geometry, textures and cameras.
            kind: "planes" (colour-noise textures, what the tests pin) or "objects" (pictures a person recognises).
        """
        prefix = "" if kind == "planes" else f"{kind}_"
        scene_dir = make_synthetic_scene(
            Path(root) / f"{prefix}seed{scene_seed}_{height}x{width}_{n_frames}",
            height=height,
            width=width,
            n_frames=n_frames,
            seed=scene_seed,
            kind=kind,
        )
        super().__init__(scene_dir=str(scene_dir), factor=1, **kwargs)
