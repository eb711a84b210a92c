"""Scene formats and ray datasets."""

from simplenerf.data.llff import LLFFDataModule

__all__ = ["LLFFDataModule"]
