"""SimpleNeRF's own parts (paper Sec. 4): augmentations (simplifiers), reliability masks, loss terms."""
