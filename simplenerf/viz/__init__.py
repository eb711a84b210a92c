"""Pictures and videos: colour maps and PNGs, validation renders, videos along a camera path, geometry export."""
