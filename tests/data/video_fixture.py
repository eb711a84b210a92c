"""A short synthetic video written with PyAV whose frames show their own number, and RealEstate-10K camera lines at
its frames' times: the RealEstate-10K download tests check that exactly the camera file's frames come out.

Frame k is one flat colour, `colour(k)`: k in base 28 in red and green, 8 levels apart (H.264 in yuv420p keeps a flat
frame's colour within two or three levels); its presentation
time is k * 1001 / 30000 s (29.97 fps, YouTube's usual rate), and its camera-file timestamp that time in
microseconds, rounded as the dataset's are (so some timestamps lie a fraction of a microsecond after their frame).
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np

TIME_BASE = Fraction(1, 30000)
TICKS = 1001  # per frame


BASE, STEP, OFFSET = 28, 8, 16


def colour(k: int) -> tuple[int, int, int]:
    return OFFSET + STEP * (k % BASE), OFFSET + STEP * (k // BASE), 128


def frame_number(image: np.ndarray) -> int:
    """The number a frame shows (its mean red and green read back)."""
    low, high = (int(round((float(image[..., c].mean()) - OFFSET) / STEP)) for c in (0, 1))
    return high * BASE + low


def timestamp(k: int) -> int:
    """Frame k's camera-file timestamp (µs)."""
    return round(k * TICKS * TIME_BASE * 1_000_000)


def write_video(path: Path, frames: list[int], width: int = 64, height: int = 48, gop: int = 12) -> Path:
    """An H.264 mp4 whose frames are the given frame numbers, each at its own time (a gap in `frames` is a gap in
    the video); a keyframe every `gop` frames, so that seeking lands between keyframes."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(30000, 1001))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.time_base = TIME_BASE
        stream.codec_context.gop_size = gop
        stream.options = {"crf": "10", "bf": "0"}
        for k in frames:
            image = np.empty((height, width, 3), dtype=np.uint8)
            image[:] = colour(k)
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts, frame.time_base = k * TICKS, TIME_BASE
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def camera_file(url: str, frames: range) -> str:
    """A RealEstate-10K camera file: the URL, then one line per frame (timestamp, intrinsics, a 3x4 matrix)."""
    lines = [url]
    for k in frames:
        pose = [1, 0, 0, 0.01 * k, 0, 1, 0, 0, 0, 0, 1, 0]
        lines.append(" ".join([str(timestamp(k)), "0.8", "1.1", "0.5", "0.5", "0", "0", *map(str, pose)]))
    return "\n".join(lines) + "\n"
