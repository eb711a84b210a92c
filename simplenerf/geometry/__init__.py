"""Camera geometry: rays of pixels, NDC, projection, the posed views, camera alignment and camera paths for videos."""
