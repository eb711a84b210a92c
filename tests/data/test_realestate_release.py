"""`simplenerf download realestate` through the real command, without network: yt-dlp is replaced by a stub module
whose YoutubeDL "downloads" a synthetic PyAV video (tests/data/video_fixture.py: each frame shows its number), the
metadata is a RealEstate10K.tar.gz made here. Checks that exactly the camera file's frames come out at the asked size,
that a gone video or a timestamp past the video's end is one line naming the clip with nothing half-written, that
complete clips are skipped, the manifest, --dry_run, and that `fit`'s loader reads what it writes."""

from __future__ import annotations

import hashlib
import io
import json
import sys
import tarfile
import types
from pathlib import Path

import cv2
import numpy as np
import pytest

from simplenerf.data.realestate import load_realestate_scene
from simplenerf.data.realestate_release import PAPER_CLIPS, parse_clip
from tests.data.download_command import run_download
from tests.data.video_fixture import camera_file, frame_number, timestamp, write_video

GOOD, GONE, SHORT = "00000000000000aa", "00000000000000bb", "00000000000000cc"


def stub_yt_dlp(videos: dict[str, Path], calls: list[tuple[str, bool]]) -> types.ModuleType:
    """A module with yt-dlp's API as simplenerf uses it: YoutubeDL(options).extract_info(url, download) copies
    `videos[url]` to the output template (or raises utils.DownloadError as yt-dlp does for a gone video)."""
    module, utils, version = (types.ModuleType(n) for n in ("yt_dlp", "yt_dlp.utils", "yt_dlp.version"))

    class DownloadError(Exception):
        pass

    class YoutubeDL:
        def __init__(self, options: dict) -> None:
            self.options = options

        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            pass

        def extract_info(self, url: str, download: bool = True) -> dict:
            calls.append((url, download))
            if url not in videos:
                raise DownloadError(f"ERROR: [youtube] {url[-11:]}: Video unavailable. This video has been removed\n"
                                    "more lines")
            info = {"format_id": "137", "ext": "mp4", "vcodec": "avc1.640028", "width": 64, "height": 48,
                    "fps": 29.97, "filesize": videos[url].stat().st_size}
            if download:
                target = Path(self.options["outtmpl"].replace("%(ext)s", "mp4"))
                target.write_bytes(videos[url].read_bytes())
                info["requested_downloads"] = [{"filepath": str(target)}]
            return info

    utils.DownloadError = DownloadError
    version.__version__ = "stub"
    module.YoutubeDL, module.utils, module.version = YoutubeDL, utils, version
    return module


@pytest.fixture()
def world(tmp_path, monkeypatch):
    """The stub yt-dlp, a 90-frame video, and metadata with three camera files: GOOD (frames 0-79: its clip, from
    frame 20, lies inside the video), GONE (its video is unavailable), SHORT (its clip runs past the video's end)."""
    video = write_video(tmp_path / "source.mp4", list(range(90)))
    urls = {GOOD: "https://www.youtube.com/watch?v=good0000000", GONE: "https://www.youtube.com/watch?v=gone0000000",
            SHORT: "https://www.youtube.com/watch?v=short000000"}
    calls: list[tuple[str, bool]] = []
    monkeypatch.setitem(sys.modules, "yt_dlp", stub_yt_dlp({urls[GOOD]: video, urls[SHORT]: video}, calls))
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for video_id, frames in ((GOOD, range(80)), (GONE, range(80)), (SHORT, range(60, 120))):
            data = camera_file(urls[video_id], frames).encode()
            member = tarfile.TarInfo(f"RealEstate10K/test/{video_id}.txt")
            member.size = len(data)
            tar.addfile(member, io.BytesIO(data))
    metadata = tmp_path / "RealEstate10K.tar.gz"
    metadata.write_bytes(buffer.getvalue())
    return types.SimpleNamespace(metadata=metadata, calls=calls, dest=tmp_path / "data" / "realestate10k",
                                 urls=urls)


def download(*args: str) -> int:
    """Runs `simplenerf download realestate ARGS` in this process; its exit status."""
    return run_download("realestate", *args)


def test_the_papers_clips_are_the_releases():
    assert [(c.id, c.start, c.frames) for c in PAPER_CLIPS] == [
        ("000c3ab189999a83", 53453400, 50), ("000db54a47bd43fe", 227894333, 50), ("0017ce4c6a39d122", 46012000, 50),
        ("002ae53df0e0afe2", 61144000, 50), ("0043978734eec081", 54387667, 50)]
    assert parse_clip("0017ce4c6a39d122") == PAPER_CLIPS[2]
    assert parse_clip("abc@123").start == 123 and parse_clip("abc").start is None


def test_clips_come_out_exact_checked_and_one_bad_clip_is_one_line(world, capsys):
    ids = [f"{GOOD}@{timestamp(20)}", GONE]
    assert download("--ids", *ids, "--metadata", str(world.metadata), "--dest", str(world.dest),
                    "--size", "32x24") == 2
    captured = capsys.readouterr()
    errors = captured.err.strip().splitlines()
    assert errors[0] == (f"simplenerf: error: clip {GONE}: its video {world.urls[GONE]} cannot be fetched: [youtube] "
                         "gone0000000: Video unavailable. This video has been removed")
    assert errors[1].startswith(f"simplenerf: error: 1 of 2 clips failed ({GONE}); the others are in")
    assert len(errors) == 2
    assert sorted(p.name for p in world.dest.iterdir()) == [".downloads", GOOD, "manifest.json"]  # no partial folder
    assert list((world.dest / ".downloads").iterdir()) == []  # the video is not kept

    clip = world.dest / GOOD
    camera_lines = (clip / f"{GOOD}.txt").read_text().splitlines()
    assert camera_lines[0] == world.urls[GOOD] and len(camera_lines) == 51
    assert [int(line.split()[0]) for line in camera_lines[1:]] == [timestamp(k) for k in range(20, 70)]
    manifest = json.loads((world.dest / "manifest.json").read_text())["clips"][GOOD]
    for k in range(20, 70):
        image = cv2.cvtColor(cv2.imread(str(clip / "frames" / f"{timestamp(k)}.png")), cv2.COLOR_BGR2RGB)
        assert image.shape == (24, 32, 3)
        assert frame_number(image) == k
        assert manifest["frames_sha256"][str(timestamp(k))] == hashlib.sha256(image.tobytes()).hexdigest()
    assert manifest["video"]["format_id"] == "137" and manifest["video"]["resolution"] == "64x48"
    assert manifest["stream"] == {"codec": "h264", "resolution": "64x48", "fps": pytest.approx(30000 / 1001)}
    assert (manifest["start"], manifest["frames"], manifest["size"]) == (timestamp(20), 50, "32x24")
    assert len(manifest["frames_sha256"]) == 50
    scene = load_realestate_scene(clip, n_views=2)  # what `fit` reads
    assert scene.views.images.shape == (50, 24, 32, 3) and scene.split.train == [10, 20]
    assert np.isclose(float(scene.views.intrinsics[0, 0, 0]), 0.8 * 32)

    fetched = len(world.calls)
    assert download("--ids", *ids, "--metadata", str(world.metadata), "--dest", str(world.dest)) == 2
    assert len(world.calls) == fetched + 1  # only the gone one is tried again: the complete clip is skipped


def test_a_timestamp_past_the_videos_end_writes_nothing(world, capsys):
    assert download("--ids", SHORT, "--metadata", str(world.metadata), "--dest", str(world.dest)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == (f"simplenerf: error: clip {SHORT}: timestamp {timestamp(90)} (µs) is not in the video: its last "
                      "frame is at 2.970 s")
    assert sorted(p.name for p in world.dest.iterdir()) == [".downloads"]


def test_dry_run_reads_the_camera_files_asks_ytdlp_and_writes_nothing(world, capsys):
    assert download("--ids", GOOD, GONE, "--metadata", str(world.metadata), "--dest", str(world.dest),
                    "--dry_run") == 0
    out = capsys.readouterr().out
    assert f"clips:    2 (2 to fetch) into {world.dest}/<id>/" in out
    assert f"  {GOOD}  50 frames from first camera line: fetch {world.urls[GOOD]}: format 137 64x48, " in out
    assert f"  {GONE}  50 frames from first camera line: cannot be fetched: clip {GONE}: its video" in out
    assert all(not download for _, download in world.calls)
    assert not world.dest.exists()


def test_without_metadata_or_yt_dlp_the_error_says_what_to_do(world, monkeypatch, capsys):
    assert download("--ids", GOOD, "--dest", str(world.dest)) == 2
    assert f"--metadata is needed for {GOOD}: the dataset's camera files" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "yt_dlp", None)  # not installed
    assert download("--ids", GOOD, "--metadata", str(world.metadata), "--dest", str(world.dest)) == 2
    err = capsys.readouterr().err
    assert err == "simplenerf: error: fetching RealEstate-10K videos needs yt-dlp: pip install 'simplenerf[data]'\n"
    assert not world.dest.exists()


def test_metadata_from_a_url_is_downloaded_checked_and_used(world, capsys):
    from tests.data.local_server import LocalServer

    data = world.metadata.read_bytes()
    with LocalServer() as server:
        server.behaviour.files["/RealEstate10K.tar.gz"] = data
        url = server.url("/RealEstate10K.tar.gz")
        assert download("--ids", GOOD, "--metadata", url, "--metadata_sha256", "cd" * 32, "--dest",
                        str(world.dest)) == 2
        assert f"has SHA-256 {hashlib.sha256(data).hexdigest()}, expected {'cd' * 32}; deleted it" in \
            capsys.readouterr().err
        assert download("--ids", GOOD, "--metadata", url, "--metadata_sha256", hashlib.sha256(data).hexdigest(),
                        "--dest", str(world.dest)) == 0
    assert (world.dest / ".downloads" / "RealEstate10K.tar.gz").read_bytes() == data
    assert len((world.dest / GOOD / f"{GOOD}.txt").read_text().splitlines()) == 51  # the first 50 camera lines
