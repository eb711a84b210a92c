"""The paper's data, one command per dataset, checked and resumable (docs/usage.md, "Data"):

    simplenerf download llff [--scenes fern horns ...] [--dest data/nerf_llff_data] [--url MIRROR] [--dry_run]
    simplenerf download realestate --metadata RealEstate10K.tar.gz [--ids ...] [--dest data/realestate10k] [--dry_run]

llff: the NeRF authors' nerf_llff_data.zip (Google Drive through gdown, or a mirror URL), resumed when cut, its size
and SHA-256 checked when known (--size, --sha256), only the chosen scenes unpacked, each checked as `fit` checks it.
realestate: the paper's five test clips (or --ids), camera files from the dataset's metadata, videos through yt-dlp,
the frames at the camera file's timestamps at 1024x576. gdown and yt-dlp: pip install 'simplenerf[data]'.
Rerunning skips what is complete and resumes what was cut; nothing appears under its final name half-written.
`simplenerf download DATASET --help` lists each one's options.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser
from simplenerf.data import llff_release as llff
from simplenerf.data import realestate_release as re10k
from simplenerf.data.downloads import (
    Expected,
    check,
    download_drive,
    download_url,
    human,
    partial_path,
    read_json,
    remote_size,
    write_json,
)
from simplenerf.errors import DataError

DATASETS = ("llff", "realestate")


def main(argv: Sequence[str]) -> None:
    argv = list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: simplenerf download {{{','.join(DATASETS)}}} [options]\n\n{__doc__}")
        return
    if argv[0] not in DATASETS:
        CommandParser("download", __doc__).error(f"unknown dataset {argv[0]!r}; choose one of: {', '.join(DATASETS)}")
    if argv[0] == "llff":
        download_llff(llff_parser().parse_args(argv[1:]))
    else:
        download_realestate(realestate_parser().parse_args(argv[1:]))


# -- LLFF -------------------------------------------------------------------------------------------------------------


def llff_parser() -> CommandParser:
    p = CommandParser("download llff", __doc__)
    p.add_argument("--scenes", nargs="+", default=list(llff.PAPER_SCENES),
                   help="scenes to unpack (default: the paper's 8); 'all': every scene of the archive")
    p.add_argument("--dest", type=Path, default=Path("data/nerf_llff_data"), help="folder of the scene folders")
    p.add_argument("--factors", type=int, nargs="+", default=list(llff.PAPER_FACTORS),
                   help="images_N folders to unpack and check (default: 4 8; 1 is images/)")
    p.add_argument("--url", help="a mirror of nerf_llff_data.zip (plain HTTP(S), resumable) instead of Google Drive")
    p.add_argument("--archive", type=Path,
                   help="where the zip is kept (default: <dest>/../nerf_llff_data.zip); an existing one is used")
    p.add_argument("--size", type=int, help="the archive's size in bytes, checked (none is published)")
    p.add_argument("--sha256", help="the archive's SHA-256, checked (none is published)")
    p.add_argument("--remove_archive", action="store_true", help="delete the zip once the scenes are unpacked")
    p.add_argument("--dry_run", action="store_true", help="say what would be downloaded, how big and where; do nothing")
    return p


def download_llff(args: argparse.Namespace) -> None:
    archive = args.archive or args.dest.parent / llff.ARCHIVE_NAME
    expected = Expected(args.size if args.size is not None else llff.ARCHIVE_EXPECTED.size,
                        (args.sha256 or llff.ARCHIVE_EXPECTED.sha256 or "").lower() or None)
    factors = tuple(dict.fromkeys(args.factors))
    if any(f < 1 for f in factors):
        raise DataError(f"--factors {' '.join(map(str, args.factors))}: each must be 1 (images/) or more")
    every = args.scenes == ["all"]
    states = {} if every else {s: llff.scene_state(args.dest / s, factors) for s in args.scenes}
    broken = {s: why for s, why in states.items() if why not in ("absent", "complete")}
    source = args.url or f"Google Drive file {llff.DRIVE_FILE_ID}"
    if args.dry_run:
        print(f"source:   {source}")
        print(f"archive:  {archive} ({_archive_state(archive, args.url, expected)})")
        print(f"checked:  size {expected.size if expected.size is not None else 'not known'}, SHA-256 "
              f"{expected.sha256 or 'not known (none is published; pass --sha256 to check it)'}")
        which = "every scene of the archive: " if every else ""
        print(f"unpack:   {which}images_{'/images_'.join(map(str, factors))} and poses_bounds.npy into {args.dest}/")
        for scene, state in states.items():
            action = {"complete": "skip (complete)", "absent": "unpack"}.get(state, f"cannot unpack: {state}")
            print(f"  {scene:<10} {action}")
        return
    if broken:
        scene, why = next(iter(broken.items()))
        raise DataError(f"{args.dest / scene} exists but is not a complete scene ({why}); delete it to unpack it again")
    if states and all(state == "complete" for state in states.values()):
        print(f"all {len(states)} scenes are complete in {args.dest}; nothing to download")
        return
    if archive.is_file():
        print(f"using {archive}")
        found = check(archive, expected, f"{archive} (delete it to download it again)")
    elif args.url:
        print(f"downloading {args.url} -> {archive}")
        found = download_url(args.url, archive, expected)
    else:
        print(f"downloading Google Drive file {llff.DRIVE_FILE_ID} -> {archive}")
        found = download_drive(llff.DRIVE_FILE_ID, archive, expected)
    checked = "checked" if expected.sha256 else "not checked: none is published; pass --sha256 to check it"
    print(f"{archive}: {found.size} bytes, SHA-256 {found.sha256} ({checked})")
    available = llff.archive_scenes(archive)
    chosen = llff.choose_scenes(available, None if every else args.scenes, archive)
    for scene in chosen:
        members_ok = llff.scene_state(args.dest / scene.name, factors)
        if members_ok == "complete":
            print(f"{scene.name}: complete in {args.dest / scene.name}, skipped")
            continue
        if members_ok != "absent":
            raise DataError(f"{args.dest / scene.name} exists but is not a complete scene ({members_ok}); delete it "
                            "to unpack it again")
        unpacked = llff.unpack_scene(archive, scene, args.dest, factors)
        llff.record(args.dest, {"size": found.size, "sha256": found.sha256}, source, unpacked)
        sizes = ", ".join(f"images_{f} {w}x{h}" for f, (w, h) in unpacked.sizes.items())
        print(f"{scene.name}: {unpacked.frames} frames ({sizes}) -> {unpacked.folder}")
    if args.remove_archive:
        archive.unlink()
        print(f"removed {archive}")


def _archive_state(archive: Path, url: str | None, expected: Expected) -> str:
    if archive.is_file():
        return f"present, {human(archive.stat().st_size)}: used, not downloaded"
    part = partial_path(archive)
    partial = f"; {human(part.stat().st_size)} already downloaded, resumed" if part.is_file() else ""
    size = expected.size if expected.size is not None else remote_size(url) if url else None
    exact = f" ({size} bytes)" if size is not None else ""
    return f"to download, {human(size)}{exact}{partial}"


# -- RealEstate-10K ---------------------------------------------------------------------------------------------------


def realestate_parser() -> CommandParser:
    p = CommandParser("download realestate", __doc__)
    p.add_argument("--ids", nargs="+", type=re10k.parse_clip, default=list(re10k.PAPER_CLIPS),
                   help="clips: ID (a paper clip's frames, else the camera file's first 50) or ID@START_TIMESTAMP "
                        "(default: the paper's 5 test clips)")
    p.add_argument("--dest", type=Path, default=Path("data/realestate10k"), help="folder of the clip folders")
    p.add_argument("--metadata",
                   help="the dataset's camera files: a folder, RealEstate10K.tar.gz, or its URL (downloaded, "
                        "resumable, into <dest>/.downloads/)")
    p.add_argument("--metadata_sha256", help="the metadata archive's SHA-256, checked when downloading it")
    p.add_argument("--frames", type=int, default=re10k.CLIP_FRAMES, help="camera lines per clip (default 50)")
    p.add_argument("--size", default="x".join(map(str, re10k.PAPER_SIZE)),
                   help="frame size WIDTHxHEIGHT (default: the paper's 1024x576)")
    p.add_argument("--format", default=re10k.VIDEO_FORMAT, help="yt-dlp's format selection")
    p.add_argument("--keep_videos", action="store_true", help="keep the videos in <dest>/.downloads/")
    p.add_argument("--dry_run", action="store_true",
                   help="say what would be fetched (yt-dlp's format and size when it can ask) and where; write nothing")
    return p


def parse_size(text: str) -> tuple[int, int]:
    width, _, height = text.lower().partition("x")
    if not (width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        raise DataError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 1024x576")
    return int(width), int(height)


def download_realestate(args: argparse.Namespace) -> None:
    size = parse_size(args.size)
    if args.frames < 1:
        raise DataError(f"--frames {args.frames}: expected a positive number of camera lines")
    clips = [re10k.Clip(c.id, c.start, args.frames) for c in dict((c.id, c) for c in args.ids).values()]
    states = {c.id: re10k.clip_state(args.dest / c.id, c.frames) for c in clips}
    todo = [c for c in clips if states[c.id] != "complete"]
    downloads = args.dest / ".downloads"
    if args.dry_run:
        dry_run_realestate(args, clips, states, size)
        return
    if not todo:
        print(f"all {len(clips)} clips are complete in {args.dest}; nothing to fetch")
        return
    if not args.metadata:
        raise DataError(f"--metadata is needed for {', '.join(c.id for c in todo)}: the dataset's camera files (a "
                        "folder, RealEstate10K.tar.gz or its URL; google.github.io/realestate10k/download.html)")
    re10k.require_yt_dlp()
    metadata = metadata_path(args.metadata, downloads, args.metadata_sha256)
    texts = re10k.read_camera_texts(metadata, [c.id for c in todo])
    manifest_path = args.dest / re10k.MANIFEST
    failed = []
    for number, clip in enumerate(todo, start=1):
        print(f"[{number}/{len(todo)}] clip {clip.id}")
        try:
            if states[clip.id] != "absent":
                raise re10k.ClipError(clip.id, f"{args.dest / clip.id} exists but is not complete ({states[clip.id]});"
                                      " delete it to fetch it again")
            if clip.id not in texts:
                raise re10k.ClipError(clip.id, f"{metadata} has no camera file {clip.id}.txt")
            entry = fetch_clip(clip, re10k.clip_cameras(clip, texts[clip.id]), args, downloads, size)
        except DataError as e:
            print(f"simplenerf: error: {e}", file=sys.stderr)
            failed.append(clip.id)
            if (downloads / clip.id).is_dir() and not any((downloads / clip.id).iterdir()):
                (downloads / clip.id).rmdir()  # nothing to resume from
            continue
        manifest = read_json(manifest_path)
        manifest.setdefault("clips", {})[clip.id] = entry
        write_json(manifest_path, manifest)
        print(f"  {clip.frames} frames at {size[0]}x{size[1]} -> {args.dest / clip.id}")
    if failed:
        raise DataError(f"{len(failed)} of {len(todo)} clips failed ({', '.join(failed)}); the others are in "
                        f"{args.dest}; run the same command again to retry")


def metadata_path(metadata: str, downloads: Path, sha256: str | None) -> Path:
    """The metadata as a local folder or archive: a URL is downloaded (resumable) into `downloads`."""
    if not metadata.startswith(("http://", "https://")):
        return Path(metadata)
    dest = downloads / (Path(metadata.split("?")[0]).name or "RealEstate10K.tar.gz")
    if not dest.is_file():
        print(f"downloading {metadata} -> {dest}")
        download_url(metadata, dest, Expected(sha256=sha256.lower() if sha256 else None))
    elif sha256:
        check(dest, Expected(sha256=sha256.lower()), f"{dest} (delete it to download it again)")
    return dest


def fetch_clip(clip: re10k.Clip, cameras: re10k.ClipCameras, args: argparse.Namespace, downloads: Path,
               size: tuple[int, int]) -> dict:
    """One clip: its video fetched, its frames cut, written, checked; the manifest entry."""
    import av

    video_folder = downloads / clip.id
    print(f"  fetching {cameras.url}")
    video = re10k.fetch_video(clip.id, cameras.url, video_folder, args.format)
    print(f"  format {video.format_id} ({video.ext}, {video.vcodec}, {video.resolution}); cutting "
          f"{len(cameras.timestamps)} frames")
    frames = re10k.write_clip(clip, cameras, video.path, args.dest, size)
    found = check(video.path, Expected(), str(video.path))
    if not args.keep_videos:
        shutil.rmtree(video_folder, ignore_errors=True)
    return {
        "url": cameras.url, "start": cameras.timestamps[0], "frames": len(cameras.timestamps),
        "size": f"{size[0]}x{size[1]}",
        "video": {"format_id": video.format_id, "ext": video.ext, "vcodec": video.vcodec,
                  "resolution": video.resolution, "fps": video.fps, "bytes": found.size,
                  "sha256": found.sha256},
        "tools": {"yt_dlp": _version("yt_dlp"), "av": av.__version__},
        **frames,
    }


def _version(module: str) -> str | None:
    try:
        return __import__(f"{module}.version", fromlist=["__version__"]).__version__
    except (ImportError, AttributeError):
        return None


def dry_run_realestate(args: argparse.Namespace, clips: list[re10k.Clip], states: dict[str, str],
                       size: tuple[int, int]) -> None:
    todo = [c for c in clips if states[c.id] != "complete"]
    print(f"clips:    {len(clips)} ({len(todo)} to fetch) into {args.dest}/<id>/ (<id>.txt + frames/<timestamp>.png "
          f"at {size[0]}x{size[1]})")
    metadata = args.metadata or "not given (--metadata: a folder, RealEstate10K.tar.gz or its URL)"
    if args.metadata and args.metadata.startswith(("http://", "https://")):
        metadata += f" (to download, {human(remote_size(args.metadata))}, into {args.dest / '.downloads'})"
    print(f"metadata: {metadata}")
    texts = {}
    if args.metadata and not args.metadata.startswith(("http://", "https://")) and todo:
        texts = re10k.read_camera_texts(Path(args.metadata), [c.id for c in todo])
    for clip in clips:
        start = "first camera line" if clip.start is None else f"timestamp {clip.start}"
        line = f"  {clip.id}  {clip.frames} frames from {start}: "
        if states[clip.id] == "complete":
            print(line + "skip (complete)")
            continue
        if states[clip.id] != "absent":
            print(line + f"exists but is not complete ({states[clip.id]}); delete it to fetch it again")
            continue
        if clip.id not in texts:
            print(line + "fetch (video URL: from its camera file)")
            continue
        try:
            cameras = re10k.clip_cameras(clip, texts[clip.id])
            video = re10k.probe_video(clip.id, cameras.url, args.format)
            print(line + f"fetch {cameras.url}: format {video.format_id} {video.resolution}, {human(video.filesize)}")
        except DataError as e:
            print(line + f"cannot be fetched: {e}")
