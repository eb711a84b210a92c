"""simplenerf: SimpleNeRF (Somraj et al., SIGGRAPH Asia 2023) for few-view NeRF, as a PyTorch Lightning codebase."""

__version__ = "0.1.0"
