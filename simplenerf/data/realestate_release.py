"""The paper's RealEstate-10K clips, fetched into the layout `simplenerf.data.realestate` reads
(`<dest>/<id>/{<id>.txt, frames/<timestamp>.png}`). `simplenerf download realestate` (docs/usage.md, "Data").

For each clip: the camera file `<id>.txt` from the dataset's metadata (a folder, the RealEstate10K.tar.gz archive or
its URL), cut to the clip's lines (line 1, the video URL, kept); the video through yt-dlp (`pip install
'simplenerf[data]'`); the frames at the camera lines' timestamps (`simplenerf.data.video_frames`, PyAV) resized to the
paper's 1024x576; the clip checked as `fit` reads it; then the folder renamed into place, so that a clip folder exists
only complete. `<dest>/manifest.json` records per clip the video's format and resolution and each frame's SHA-256
(of its decoded RGB pixels): the authors warn that videos fetched today may differ from theirs, and two users can
compare these.

The paper's clips (PAPER_CLIPS): the five test videos the release maps to its scenes 0, 1, 3, 4, 6
(src/database_utils/real_estate/data_organizers/VideoNameMapper.py), 50 consecutive camera lines from each start
timestamp (DataExtractor01.py: 53453400, 227894333, 46012000, 61144000, 54387667), frames at 1024x576.
"""

from __future__ import annotations

import hashlib
import shutil
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simplenerf.data.llff import read_same_size_images
from simplenerf.data.realestate import frame_path, read_camera_file
from simplenerf.data.video_frames import VideoStream, cut_frames
from simplenerf.errors import DataError

PAPER_SIZE = (1024, 576)  # width, height (the paper, Sec. 5.1; the release's DataExtractor01 resolution (576, 1024))
CLIP_FRAMES = 50
MANIFEST = "manifest.json"
# yt-dlp's format choice: a video-only stream (no audio to merge, so no ffmpeg binary), H.264 when there is one (PyAV
# decodes it everywhere), at most 1080 lines (the frames are written at 576).
VIDEO_FORMAT = "bestvideo[height<=1080][vcodec^=avc1]/bestvideo[height<=1080]/best[height<=1080]/best"


@dataclass(frozen=True)
class Clip:
    """A clip: the video id (its camera file's name), the timestamp (µs) of its first camera line (None: the camera
    file's first) and its number of consecutive camera lines."""

    id: str
    start: int | None = None
    frames: int = CLIP_FRAMES


PAPER_CLIPS = (
    Clip("000c3ab189999a83", 53453400),  # the release's scene 0
    Clip("000db54a47bd43fe", 227894333),  # 1
    Clip("0017ce4c6a39d122", 46012000),  # 3
    Clip("002ae53df0e0afe2", 61144000),  # 4
    Clip("0043978734eec081", 54387667),  # 6
)


class ClipError(DataError):
    """One clip cannot be made (its camera file, its video, a frame); the message names the clip."""

    def __init__(self, clip: str, reason: str) -> None:
        super().__init__(f"clip {clip}: {reason}")
        self.clip = clip


def parse_clip(text: str) -> Clip:
    """`ID` (a paper clip's start and length, else the camera file's first 50 lines) or `ID@START` (µs)."""
    video_id, _, start = text.partition("@")
    if not video_id or (start and not start.isdigit()):
        raise DataError(f"--ids {text!r}: expected a video id, optionally @ the first frame's timestamp in µs "
                        "(e.g. 000c3ab189999a83@53453400)")
    paper = {c.id: c for c in PAPER_CLIPS}
    if start:
        return Clip(video_id, int(start))
    return paper.get(video_id, Clip(video_id))


# -- camera files -----------------------------------------------------------------------------------------------------


def read_camera_texts(metadata: Path, ids: list[str]) -> dict[str, str]:
    """The camera files `<id>.txt` of `ids` found in `metadata`: a folder (the unpacked dataset, its test/ or train/,
    or a folder of camera files) or a tar archive of it (RealEstate10K.tar.gz). Ids not found are left out."""
    found: dict[str, str] = {}
    if metadata.is_dir():
        for video_id in ids:
            for candidate in (metadata / f"{video_id}.txt", *metadata.glob(f"*/{video_id}.txt"),
                              *metadata.glob(f"*/*/{video_id}.txt")):
                if candidate.is_file():
                    found[video_id] = candidate.read_text()
                    break
        return found
    if not metadata.is_file():
        raise DataError(f"--metadata {metadata} does not exist (the RealEstate-10K camera files: a folder or "
                        "RealEstate10K.tar.gz)")
    names = {f"{video_id}.txt": video_id for video_id in ids}
    try:
        with tarfile.open(metadata) as tar:
            for member in tar:
                video_id = names.get(Path(member.name).name)
                if video_id is not None and member.isfile() and video_id not in found:
                    found[video_id] = tar.extractfile(member).read().decode()
                    if len(found) == len(ids):
                        break
    except (tarfile.TarError, OSError, EOFError, UnicodeDecodeError) as e:
        raise DataError(f"cannot read --metadata {metadata} as a tar archive of camera files: {e}") from e
    return found


@dataclass(frozen=True)
class ClipCameras:
    """A clip's part of its camera file: the video URL, the clip's camera lines and their timestamps (µs)."""

    url: str
    lines: list[str]
    timestamps: list[int]

    def text(self) -> str:
        """The camera file as written into the clip folder: the URL line, then the clip's lines."""
        return "\n".join([self.url, *self.lines]) + "\n"


def clip_cameras(clip: Clip, text: str) -> ClipCameras:
    """The clip's lines of its camera file `text`; ClipError when the start timestamp is not among them or fewer
    than `clip.frames` lines follow it."""
    lines = text.splitlines()
    if not lines or not lines[0].strip().startswith("http"):
        raise ClipError(clip.id, "its camera file does not start with the video's URL")
    body = [line.strip() for line in lines[1:] if line.strip()]
    stamps = [line.split()[0] for line in body]
    first = 0
    if clip.start is not None:
        if str(clip.start) not in stamps:
            raise ClipError(clip.id, f"its camera file has no frame at timestamp {clip.start}")
        first = stamps.index(str(clip.start))
    chosen = body[first:first + clip.frames]
    if len(chosen) < clip.frames:
        raise ClipError(clip.id, f"its camera file has {len(chosen)} frames from timestamp {stamps[first]} on, the "
                        f"clip needs {clip.frames}")
    return ClipCameras(lines[0].strip(), chosen, [int(line.split()[0]) for line in chosen])


# -- videos -----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FetchedVideo:
    """A downloaded video and what yt-dlp says it is."""

    path: Path
    format_id: str
    ext: str
    vcodec: str
    width: int | None
    height: int | None
    fps: float | None
    filesize: int | None

    @property
    def resolution(self) -> str:
        """WIDTHxHEIGHT as yt-dlp reports it, 'unknown' when it does not."""
        return f"{self.width}x{self.height}" if self.width and self.height else "unknown"


def require_yt_dlp():
    """The yt_dlp module; DataError saying how to install it."""
    try:
        import yt_dlp
    except ImportError:
        raise DataError("fetching RealEstate-10K videos needs yt-dlp: pip install 'simplenerf[data]'") from None
    return yt_dlp


def _reason(error: Exception) -> str:
    """yt-dlp's error as one short line: 'Video unavailable', 'not available in your country', ..."""
    text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return text.removeprefix("ERROR: ").strip()


def _fetched(info: dict, path: Path) -> FetchedVideo:
    return FetchedVideo(path, str(info.get("format_id")), str(info.get("ext")), str(info.get("vcodec")),
                        info.get("width"), info.get("height"), info.get("fps"),
                        info.get("filesize") or info.get("filesize_approx"))


def fetch_video(clip: str, url: str, folder: Path, video_format: str = VIDEO_FORMAT) -> FetchedVideo:
    """Downloads the clip's video into `folder` with yt-dlp (which resumes its own partial file); ClipError with
    yt-dlp's reason when the video is gone, private or region-locked."""
    yt_dlp = require_yt_dlp()
    folder.mkdir(parents=True, exist_ok=True)
    options = {"format": video_format, "outtmpl": str(folder / "video.%(ext)s"), "quiet": True, "no_warnings": True,
               "noprogress": True, "continuedl": True, "retries": 3}
    try:
        with yt_dlp.YoutubeDL(options) as ydl:
            info = ydl.extract_info(url, download=True)
    except yt_dlp.utils.DownloadError as e:
        raise ClipError(clip, f"its video {url} cannot be fetched: {_reason(e)}") from None
    downloads = info.get("requested_downloads") or [{}]
    path = Path(downloads[0].get("filepath") or ydl.prepare_filename(info))
    if not path.is_file():
        raise ClipError(clip, f"yt-dlp reported {path} but wrote no such file")
    return _fetched(info, path)


def probe_video(clip: str, url: str, video_format: str = VIDEO_FORMAT) -> FetchedVideo:
    """What yt-dlp would fetch (format, size) without downloading it, for --dry_run; ClipError as fetch_video."""
    yt_dlp = require_yt_dlp()
    try:
        with yt_dlp.YoutubeDL({"format": video_format, "quiet": True, "no_warnings": True}) as ydl:
            info = ydl.extract_info(url, download=False)
    except yt_dlp.utils.DownloadError as e:
        raise ClipError(clip, f"its video {url} cannot be fetched: {_reason(e)}") from None
    return _fetched(info, Path())


# -- writing a clip ---------------------------------------------------------------------------------------------------


def pixels_sha256(image: np.ndarray) -> str:
    """SHA-256 of an image's RGB pixels as uint8 [H, W, 3] bytes (independent of the PNG encoder)."""
    return hashlib.sha256(np.ascontiguousarray(image, dtype=np.uint8).tobytes()).hexdigest()


def resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`image` at (width, height); area averaging when shrinking (anti-aliased), bicubic when enlarging."""
    if (image.shape[1], image.shape[0]) == size:
        return image
    shrink = size[0] < image.shape[1]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC)


def check_clip(folder: Path, frames: int, size: tuple[int, int] | None = None) -> None:
    """`fit`'s reading of a clip folder: the camera file `<id>.txt` parses, has `frames` lines, each with its
    `frames/<timestamp>.png`, all of one size (`size` (width, height) when given); DataError otherwise."""
    stamps, _, _ = read_camera_file(folder / f"{folder.name}.txt")
    if len(stamps) != frames:
        raise DataError(f"{folder / f'{folder.name}.txt'} has {len(stamps)} frames, expected {frames}")
    paths = []
    for stamp in stamps:
        path = frame_path(folder / "frames", stamp)
        if path is None:
            raise DataError(f"{folder / 'frames'} has no frame {stamp}.png")
        paths.append(path)
    images = read_same_size_images(paths)
    if size is not None and (images[0].shape[1], images[0].shape[0]) != size:
        raise DataError(f"{paths[0]} is {images[0].shape[1]}x{images[0].shape[0]}, expected {size[0]}x{size[1]}")


def clip_state(folder: Path, frames: int) -> str:
    """'absent', 'complete' (as `fit` reads it, without decoding the frames) or why it is not."""
    if not folder.exists():
        return "absent"
    try:
        stamps, _, _ = read_camera_file(folder / f"{folder.name}.txt")
        if len(stamps) != frames:
            return f"its camera file has {len(stamps)} frames, expected {frames}"
        missing = [s for s in stamps if frame_path(folder / "frames", s) is None]
        if missing:
            return f"{len(missing)} frames missing (first: {missing[0]}.png)"
    except DataError as e:
        return str(e)
    return "complete"


def write_clip(clip: Clip, cameras: ClipCameras, video: Path, dest: Path, size: tuple[int, int]) -> dict:
    """Cuts the clip's frames from `video`, writes the clip into a temporary folder in `dest`, checks it as `fit`
    reads it and renames it to `dest/<id>`. Returns the manifest entry's frame part; ClipError names the clip."""
    try:
        stream, images = cut_frames(video, cameras.timestamps)
    except DataError as e:
        raise ClipError(clip.id, str(e)) from None
    dest.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{clip.id}.", suffix=".partial", dir=dest))
    try:
        folder = tmp / clip.id
        (folder / "frames").mkdir(parents=True)
        (folder / f"{clip.id}.txt").write_text(cameras.text())
        checksums = {}
        for stamp, image in zip(cameras.timestamps, images, strict=True):
            image = resize(image, size)
            if not cv2.imwrite(str(folder / "frames" / f"{stamp}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
                raise ClipError(clip.id, f"cannot write {folder / 'frames' / f'{stamp}.png'}")
            checksums[str(stamp)] = pixels_sha256(image)
        check_clip(folder, clip.frames, size)
        if (dest / clip.id).exists():
            raise ClipError(clip.id, f"{dest / clip.id} appeared while it was being made; leaving it as it is")
        folder.rename(dest / clip.id)
    except DataError as e:
        raise e if isinstance(e, ClipError) else ClipError(clip.id, str(e)) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"stream": stream_entry(stream), "frames_sha256": checksums,
            "clip_sha256": hashlib.sha256("".join(checksums.values()).encode()).hexdigest()}


def stream_entry(stream: VideoStream) -> dict:
    return {"codec": stream.codec, "resolution": f"{stream.width}x{stream.height}", "fps": stream.fps}
