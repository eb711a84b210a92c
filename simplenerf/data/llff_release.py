"""The NeRF authors' LLFF release (`nerf_llff_data.zip`): fetched, checked, and only the chosen scenes unpacked into
the layout `simplenerf.data.llff` reads (`<dest>/<scene>/{poses_bounds.npy, images_N/}`), each scene checked as `fit`
checks it before it gets its final name. `simplenerf download llff` (docs/usage.md, "Data").

The archive is the one the NeRF release's Google Drive folder holds (drive folder 128yBriW1IG_3NJ5Rp7APSTZsJqdJdfc1;
the SimpleNeRF release's src/database_utils/README.md links the file itself, id 16VnMcF1KJYxN9QId6TClMsZRahHNMW5g).
Neither release publishes the archive's size or SHA-256, and none is stated here: ARCHIVE_EXPECTED is unknown, so a
download is checked only against --size / --sha256 when given, and its digest is printed and kept in the manifest
for the next user to check against.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from simplenerf.data.downloads import Expected, read_json, write_json
from simplenerf.data.llff import check_scene, image_dir, read_same_size_images
from simplenerf.errors import DataError

DRIVE_FILE_ID = "16VnMcF1KJYxN9QId6TClMsZRahHNMW5g"  # nerf_llff_data.zip (the SimpleNeRF release's README links it)
ARCHIVE_NAME = "nerf_llff_data.zip"
ARCHIVE_EXPECTED = Expected(size=None, sha256=None)  # UNKNOWN: no published size or SHA-256 (module docstring)
PAPER_SCENES = ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex")  # supplement, Database
PAPER_FACTORS = (4, 8)  # images_4: the paper's resolution (1008x756); images_8: the CPU configs'
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class ArchiveScene:
    """A scene inside the archive: its name and the member-name prefix of its folder (`nerf_llff_data/fern/`)."""

    name: str
    prefix: str


@dataclass(frozen=True)
class UnpackedScene:
    """A scene written to disk and checked: its folder, frame count and the image size of each factor."""

    name: str
    folder: Path
    frames: int
    sizes: dict[int, tuple[int, int]] = field(default_factory=dict)  # factor -> (width, height)


def archive_scenes(archive: Path) -> dict[str, ArchiveScene]:
    """Every scene of an LLFF archive: each folder that holds a poses_bounds.npy, by folder name."""
    try:
        with zipfile.ZipFile(archive) as zf:
            names = zf.namelist()
    except (OSError, zipfile.BadZipFile) as e:
        raise DataError(f"cannot read {archive} as a zip archive: {e} (delete it and download it again)") from e
    scenes = {}
    for name in names:
        path = PurePosixPath(name)
        if path.name == "poses_bounds.npy" and path.parent.name:
            scenes[path.parent.name] = ArchiveScene(path.parent.name, f"{path.parent.as_posix()}/")
    return dict(sorted(scenes.items()))


def choose_scenes(available: dict[str, ArchiveScene], wanted: list[str] | None, archive: Path) -> list[ArchiveScene]:
    """The scenes `wanted` (None: all of the archive's); DataError naming those the archive does not have."""
    if wanted is None:
        return list(available.values())
    missing = [s for s in wanted if s not in available]
    if missing:
        raise DataError(f"{archive} has no scene {', '.join(missing)}; it has: {', '.join(available) or 'none'} "
                        "(a scene is a folder with poses_bounds.npy)")
    return [available[s] for s in dict.fromkeys(wanted)]


def members(zf: zipfile.ZipFile, scene: ArchiveScene, factors: tuple[int, ...]) -> list[zipfile.ZipInfo]:
    """The archive members of `scene` that `fit` reads: poses_bounds.npy and images_N/* for each factor; DataError
    when a factor's folder is not in the archive, or a member would land outside the scene folder."""
    wanted_dirs = [image_dir(Path(), f).name for f in factors]
    chosen, found = [], set()
    for info in zf.infolist():
        if not info.filename.startswith(scene.prefix) or info.is_dir():
            continue
        relative = PurePosixPath(info.filename[len(scene.prefix):])
        if relative.is_absolute() or ".." in relative.parts:
            raise DataError(f"archive member {info.filename!r} would be written outside its scene folder")
        if relative.as_posix() == "poses_bounds.npy" or (len(relative.parts) == 2 and relative.parts[0] in wanted_dirs):
            chosen.append(info)
            found.add(relative.parts[0])
    absent = [d for d in wanted_dirs if d not in found]
    if absent:
        raise DataError(f"scene {scene.name} of the archive has no {', '.join(absent)} (choose others with --factors)")
    return chosen


def check_unpacked(folder: Path, name: str, factors: tuple[int, ...]) -> UnpackedScene:
    """`fit`'s checks of an LLFF scene for each factor: poses_bounds.npy, as many images as poses, one size."""
    frames, sizes = 0, {}
    for factor in factors:
        paths, poses = check_scene(folder, factor)
        images = read_same_size_images(paths)
        frames, sizes[factor] = len(poses), (images[0].shape[1], images[0].shape[0])
    return UnpackedScene(name, folder, frames, sizes)


def unpack_scene(archive: Path, scene: ArchiveScene, dest: Path, factors: tuple[int, ...]) -> UnpackedScene:
    """Unpacks one scene into a temporary folder in `dest`, checks it as `fit` would, then renames it to
    `dest/<scene>`: the scene folder exists only complete."""
    dest.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{scene.name}.", suffix=".partial", dir=dest))
    try:
        with zipfile.ZipFile(archive) as zf:
            for info in members(zf, scene, factors):
                target = tmp / scene.name / info.filename[len(scene.prefix):]
                target.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(info) as src, open(target, "wb") as out:
                    shutil.copyfileobj(src, out)
        checked = check_unpacked(tmp / scene.name, scene.name, factors)
        (tmp / scene.name).rename(dest / scene.name)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as e:
        raise DataError(f"cannot unpack scene {scene.name} from {archive}: {e}") from e
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return UnpackedScene(checked.name, dest / scene.name, checked.frames, checked.sizes)


def scene_state(folder: Path, factors: tuple[int, ...]) -> str:
    """'absent', 'complete' (passes fit's checks for every factor) or why it does not."""
    if not folder.exists():
        return "absent"
    try:
        for factor in factors:
            check_scene(folder, factor)
    except DataError as e:
        return str(e)
    return "complete"


def record(dest: Path, archive_digest: dict, source: str, scene: UnpackedScene) -> None:
    """Adds a scene to `<dest>/manifest.json`: the archive it came from (source, size, SHA-256) and what was
    checked (frames, image sizes per factor)."""
    manifest = read_json(dest / MANIFEST)
    manifest["archive"] = {"name": ARCHIVE_NAME, "source": source, **archive_digest}
    manifest.setdefault("scenes", {})[scene.name] = {
        "frames": scene.frames,
        "images": {f"images_{f}": f"{w}x{h}" for f, (w, h) in sorted(scene.sizes.items())},
    }
    write_json(dest / MANIFEST, manifest)
