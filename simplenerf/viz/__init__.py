"""Pictures and videos: colour maps and PNGs, validation renders, camera trajectories, spiral videos."""
