"""The NeRF itself (paper Sec. 3): positional encoding, fields, sampling, volume rendering, coarse + fine model."""
