"""Frames of a video at given timestamps, decoded with PyAV (no ffmpeg binary), exact to the frame.

A RealEstate-10K camera line's timestamp (microseconds) names a frame of the video. The frame taken for it is the
first whose presentation time is at or after the timestamp cut to whole milliseconds: what the authors' release gets
from `ffmpeg -ss <timestamp in ms> -i video -vframes 1` (src/database_utils/real_estate/data_organizers/
DataExtractor01.py). The camera file's timestamps are the video's frame times rounded to the microsecond, so the cut
to milliseconds keeps a timestamp rounded up past its frame's time from taking the next frame. A timestamp past the
video's last frame, or one in a gap of more than two frame durations, is not in the video: VideoError.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from simplenerf.errors import DataError

MAX_GAP_FRAMES = 2  # a frame further than this many frame durations after its timestamp: the moment is missing


class VideoError(DataError):
    """A video cannot be decoded, or a timestamp is not in it."""


@dataclass(frozen=True)
class VideoStream:
    """What a video's first video stream is: codec, size and frame rate, for the manifest."""

    codec: str
    width: int
    height: int
    fps: float | None


def frame_time(timestamp_us: int) -> Fraction:
    """The time (seconds) whose frame a camera-file timestamp names: the timestamp cut to whole milliseconds."""
    return Fraction(int(timestamp_us) // 1000, 1000)


def cut_frames(video: Path, timestamps: list[int]) -> tuple[VideoStream, list[np.ndarray]]:
    """The frames [H, W, 3] uint8 RGB at `timestamps` (microseconds, any order) of `video`'s first video stream."""
    try:
        return _cut(video, timestamps, seek=True)
    except av.FFmpegError as e:
        raise VideoError(f"cannot decode {video}: {e}") from e


def _cut(video: Path, timestamps: list[int], seek: bool) -> tuple[VideoStream, list[np.ndarray]]:
    targets = [frame_time(t) for t in timestamps]
    order = sorted(range(len(targets)), key=targets.__getitem__)
    frames: list[np.ndarray | None] = [None] * len(targets)
    with av.open(str(video)) as container:
        if not container.streams.video:
            raise VideoError(f"{video} has no video stream")
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = stream.average_rate or stream.guessed_rate
        info = VideoStream(stream.codec_context.name, stream.codec_context.width, stream.codec_context.height,
                           float(rate) if rate else None)
        period = Fraction(1) / Fraction(rate) if rate else None
        start = targets[order[0]] - 1 if order else 0
        seeked = seek and start > 0
        if seeked:  # to the keyframe at or before one second ahead of the first timestamp
            container.seek(int(start / stream.time_base), stream=stream, backward=True, any_frame=False)
        i, last = 0, None
        for frame in container.decode(stream):
            if frame.pts is None:
                continue
            time = frame.pts * stream.time_base
            if last is None and seeked and time > targets[order[0]]:
                break  # the seek landed past the first timestamp: decode from the start instead (below)
            image = None
            while i < len(order) and targets[order[i]] <= time:
                t = timestamps[order[i]]
                if period is not None and time - targets[order[i]] > MAX_GAP_FRAMES * period:
                    raise VideoError(f"timestamp {t} (µs) is not in the video: its frames jump from "
                                     f"{float(last or 0):.3f} s to {float(time):.3f} s")
                image = frame.to_ndarray(format="rgb24") if image is None else image
                frames[order[i]] = image
                i += 1
            if i == len(order):
                break
            last = time
        else:
            last_text = "no frame" if last is None else f"its last frame is at {float(last):.3f} s"
            if i < len(order):
                raise VideoError(f"timestamp {timestamps[order[i]]} (µs) is not in the video: {last_text}")
    if i < len(order):  # the seek overshot
        return _cut(video, timestamps, seek=False)
    return info, [f for f in frames if f is not None]
