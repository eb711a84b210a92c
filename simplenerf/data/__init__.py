"""Scene formats and ray datasets."""

from simplenerf.data.llff import LLFFDataModule
from simplenerf.data.realestate import RealEstateDataModule

__all__ = ["LLFFDataModule", "RealEstateDataModule"]
