"""Camera geometry: rays of pixels, NDC, projection, and the posed train views (`Cameras`)."""
