"""The built-in synthetic scene: textured planes ray-traced analytically with exact depth, in the LLFF layout."""
