"""simplenerf.data.video_frames: the frames at camera-file timestamps, exact to the frame, on a synthetic video whose
frames show their own number (tests/data/video_fixture.py); timestamps that are not in the video are errors."""

from __future__ import annotations

from fractions import Fraction

import pytest

from simplenerf.data.video_frames import VideoError, cut_frames, frame_time
from tests.data.video_fixture import frame_number, timestamp, write_video


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("video") / "video.mp4", list(range(90)))


def test_frame_time_cuts_to_milliseconds():
    assert frame_time(53486767) == frame_time(53486000) == Fraction(53486, 1000)
    assert timestamp(2) == 66733  # 2 * 1001 / 30000 s = 66733.33 µs


def test_exactly_the_camera_files_frames_come_out(video):
    wanted = list(range(37, 87))  # 50 consecutive frames after a seek between keyframes (gop 12)
    stream, images = cut_frames(video, [timestamp(k) for k in wanted])
    assert [frame_number(image) for image in images] == wanted
    assert (stream.codec, stream.width, stream.height) == ("h264", 64, 48)
    assert stream.fps == pytest.approx(30000 / 1001)
    assert images[0].shape == (48, 64, 3)


def test_order_of_timestamps_is_kept_and_the_first_frame_is_reachable(video):
    wanted = [20, 0, 5, 5, 89]
    _, images = cut_frames(video, [timestamp(k) for k in wanted])
    assert [frame_number(image) for image in images] == wanted


def test_a_timestamp_rounded_past_its_frame_still_takes_that_frame(video):
    # timestamp(1) = 33367 µs lies 0.33 µs after frame 1 (33366.67 µs); a first frame at or after it would be frame 2.
    assert timestamp(1) * 30000 > 1 * 1001 * 1_000_000
    _, images = cut_frames(video, [timestamp(1)])
    assert frame_number(images[0]) == 1


def test_a_timestamp_past_the_end_is_not_in_the_video(video):
    with pytest.raises(VideoError, match=rf"timestamp {timestamp(95)} \(µs\) is not in the video: its last frame is "
                                         r"at 2\.970 s"):
        cut_frames(video, [timestamp(80), timestamp(95)])


def test_a_timestamp_in_a_gap_is_not_in_the_video(tmp_path):
    gapped = write_video(tmp_path / "gap.mp4", [*range(0, 30), *range(60, 90)])
    _, images = cut_frames(gapped, [timestamp(29), timestamp(60)])
    assert [frame_number(image) for image in images] == [29, 60]
    with pytest.raises(VideoError, match=rf"timestamp {timestamp(45)} \(µs\) is not in the video: its frames jump "
                                         r"from 0\.968 s to 2\.002 s"):
        cut_frames(gapped, [timestamp(45)])


def test_a_file_that_is_not_a_video_is_one_line(tmp_path):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    with pytest.raises(VideoError, match=f"cannot decode {bad}"):
        cut_frames(bad, [0])
