"""The release's on-disk data layouts, built from this project's data folders (LLFF and RealEstate-10K).

The release (github NagabhushanSN95/SimpleNeRF, c429746) reads a scene through its own loaders:
- LLFF, `data_loaders/NerfLlffDataLoader01.py`: under `<root>/data/databases/NeRF_LLFF/data/`,
  `all/database_data/<scene>/{rgb<suffix>/NNNN.png, CameraExtrinsics.csv, CameraIntrinsics<suffix>.csv,
  DepthBounds.csv}` and `all/estimated_depths/DE0n/<scene>/estimated_depths<suffix>/NNNN.csv`, with NNNN the frame
  number (the image's rank in name order, as its `database_utils/nerf_llff/data_organizers/DataExtractor01.py` numbers
  them), suffix `_down4` for images_4 and `_down8` for images_8 (that DataExtractor writes both).
- RealEstate-10K, `data_loaders/RealEstateDataLoader01.py`: under `<root>/data/databases/RealEstate10K/data/`,
  `test/database_data/<scene_num:05>/{rgb/NNNN.png, CameraExtrinsics.csv, CameraIntrinsics.csv}` and
  `test/estimated_depths/DE0n/<scene_num:05>/estimated_depths/NNNN.csv`, with NNNN the frame's line in the clip of
  50 consecutive camera-file lines from the scene's start timestamp (its
  `database_utils/real_estate/data_organizers/DataExtractor01.py`, demo1: scene 0 = video 000c3ab189999a83 from
  timestamp 53453400, step 1). The matrices are made by that DataExtractor's own `compute_extrinsic_matrices` /
  `compute_intrinsic_matrices` (imported from the release at run time), so they carry its float32 rounding.
- Both: the committed split CSVs `train_test_sets/setNN/{Train,Validation,Test}VideosData.csv`, copied from the
  release's repository.

Nothing here is the release's code: the layout is written from what its loaders read. LLFF cameras come from
`poses_bounds.npy` (the release extracted them from COLMAP's `sparse/0`, which is not in this project's data): the
LLFF c2w [down, right, back] becomes an OpenCV world-to-camera matrix (x right, y down, z forward), the focal is
hwf's scaled to the image width, the principal point the image centre (as that DataExtractor sets it).
"""

from __future__ import annotations

import importlib
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

LLFF_DB = "data/databases/NeRF_LLFF/data"
REALESTATE_DB = "data/databases/RealEstate10K/data"
# The release's RealEstate-10K scenes (database_utils/real_estate/data_organizers/VideoNameMapper.py, DataExtractor01
# demo1): scene number -> video id and the clip's first timestamp.
REALESTATE_SCENES = {0: ("000c3ab189999a83", 53453400), 1: ("000db54a47bd43fe", 227894333),
                     3: ("0017ce4c6a39d122", 46012000), 4: ("002ae53df0e0afe2", 61144000),
                     6: ("0043978734eec081", 54387667)}
CLIP_LENGTH = 50  # DataExtractor01 demo1: num_frames_per_scene


class ReleaseRepo:
    """Files of the release's repository: from its checkout (the folder above `src/`) or, where that has no `data/`
    (an extract of `src/` only), from its git directory."""

    def __init__(self, release_src: Path, release_git: Path | None = None) -> None:
        self.src, self.root, self.git = Path(release_src), Path(release_src).parent, release_git

    def read(self, relpath: str) -> bytes:
        path = self.root / relpath
        if path.is_file():
            return path.read_bytes()
        if self.git is None:
            raise FileNotFoundError(f"{path} is missing and no --release-git was given to read it from")
        return subprocess.run(["git", "-C", str(self.git), "show", f"HEAD:{relpath}"], check=True,
                              capture_output=True).stdout

    def listing(self, folder: str) -> list[str]:
        """Paths (relative to the repository root) of the files under `folder`."""
        path = self.root / folder
        if path.is_dir():
            return sorted(str(p.relative_to(self.root)) for p in path.rglob("*") if p.is_file())
        if self.git is None:
            raise FileNotFoundError(f"{path} is missing and no --release-git was given to read it from")
        out = subprocess.run(["git", "-C", str(self.git), "ls-tree", "-r", "--name-only", "HEAD", folder],
                             check=True, capture_output=True, text=True).stdout
        return sorted(out.split())

    def copy_tree(self, folder: str, dest_root: Path) -> None:
        """Copies the release's `folder` (and everything under it) to the same relative place under `dest_root`."""
        for relpath in self.listing(folder):
            target = dest_root / relpath
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(self.read(relpath))

    def import_module(self, name: str):
        """A module of the release, imported from its `src/` (no bytecode written there)."""
        sys.dont_write_bytecode = True
        if str(self.src) not in sys.path:
            sys.path.insert(0, str(self.src))
        return importlib.import_module(name)


def _link_or_copy(source: Path, target: Path) -> None:
    if target.exists():
        return
    try:
        target.hardlink_to(source)
    except OSError:
        shutil.copyfile(source, target)


def _write_png(source: Path, target: Path) -> None:
    """The image as a PNG: PNGs are linked or copied byte for byte (lossless, what the release's DataExtractor
    re-saves), other formats decoded once and saved as PNG."""
    if target.exists():
        return
    if source.suffix.lower() == ".png":
        _link_or_copy(source, target)
        return
    import skimage.io  # the release's dependency, as its DataExtractor reads and writes frames

    skimage.io.imsave(str(target), skimage.io.imread(str(source)), check_contrast=False)


def llff_image_paths(scene_dir: Path, factor: int) -> list[Path]:
    folder = scene_dir / ("images" if factor == 1 else f"images_{factor}")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def llff_to_w2c_opencv(poses_bounds: np.ndarray) -> np.ndarray:
    """World-to-camera [N, 4, 4], OpenCV axes, from LLFF's [N, 17] rows (c2w columns [down, right, back, centre])."""
    mats = poses_bounds[:, :15].reshape(-1, 3, 5)
    c2w = np.tile(np.eye(4), (len(mats), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = mats[:, :, 1], mats[:, :, 0], -mats[:, :, 2], \
        mats[:, :, 3]
    return np.linalg.inv(c2w)


def build_llff_layout(repo: ReleaseRepo, root: Path, scene_dir: Path, factor: int) -> dict:
    """Writes scene `scene_dir` at images_{factor} into the release's LLFF layout under `root` (reused if there).

    Returns the scene's cameras as written: w2c [N, 4, 4] (OpenCV, file units), intrinsics [N, 3, 3], bounds [N, 2],
    the resolution suffix, height and width.
    """
    scene = scene_dir.name
    suffix = f"_down{factor}" if factor > 1 else ""
    db = root / LLFF_DB
    if not (db / "train_test_sets").is_dir():
        repo.copy_tree(f"{LLFF_DB}/train_test_sets", root)
    out = db / "all/database_data" / scene
    (out / f"rgb{suffix}").mkdir(parents=True, exist_ok=True)
    paths = llff_image_paths(scene_dir, factor)
    poses_bounds = np.load(scene_dir / "poses_bounds.npy")
    assert len(paths) == len(poses_bounds), (len(paths), poses_bounds.shape)
    for i, path in enumerate(paths):
        _write_png(path, out / f"rgb{suffix}/{i:04}.png")
    import skimage.io

    height, width = skimage.io.imread(str(out / f"rgb{suffix}/0000.png")).shape[:2]
    w2c = llff_to_w2c_opencv(poses_bounds)
    hwf = poses_bounds[:, :15].reshape(-1, 3, 5)[:, :, 4]
    focal = hwf[:, 2] * width / hwf[:, 1]
    intrinsics = np.zeros((len(paths), 3, 3))
    intrinsics[:, 0, 0], intrinsics[:, 1, 1] = focal, focal
    intrinsics[:, 0, 2], intrinsics[:, 1, 2], intrinsics[:, 2, 2] = width / 2, height / 2, 1.0
    bounds = poses_bounds[:, 15:17]
    np.savetxt(out / "CameraExtrinsics.csv", w2c.reshape(-1, 16), delimiter=",")
    np.savetxt(out / f"CameraIntrinsics{suffix}.csv", intrinsics.reshape(-1, 9), delimiter=",")
    np.savetxt(out / "DepthBounds.csv", bounds, delimiter=",")
    pd.DataFrame({"frame_num": np.arange(len(paths)), "image_name": [p.name for p in paths]}).to_csv(
        out / "FrameNamesMapping.csv", index=False)
    # What the loader will read back (savetxt's %.18e round-trips float64 exactly).
    return {"w2c": w2c, "intrinsics": intrinsics, "bounds": bounds, "suffix": suffix, "height": height,
            "width": width, "db": db}


def read_realestate_camera_lines(camera_file: Path) -> np.ndarray:
    """The camera file's frame lines split into fields (strings, [N, 19]), as the release's DataExtractor01 does."""
    lines = [line.strip() for line in camera_file.read_text().splitlines()]
    return np.array([line.split(" ") for line in lines[1:] if line])


def build_realestate_layout(repo: ReleaseRepo, root: Path, scene_dir: Path) -> dict:
    """Writes RealEstate-10K video `scene_dir` (<id>/<id>.txt, <id>/frames/<timestamp>.png) into the release's layout
    under `root` as the release's scene number for that video; reused if there.

    The release's DataExtractor01 takes the 50 lines from the scene's start timestamp and resizes the video frames to
    1024x576; this project has 256x256 centre crops with intrinsics adjusted in the camera file, which the layout
    takes as they are (`compute_intrinsic_matrices` with the crop's resolution).
    Returns scene_num, the w2c [50, 4, 4] and intrinsics [50, 3, 3] as written, height, width, db.
    """
    video = scene_dir.name
    matches = [num for num, (vid, _) in REALESTATE_SCENES.items() if vid == video]
    if not matches:
        raise ValueError(f"{video} is not one of the release's RealEstate-10K scenes {REALESTATE_SCENES}")
    scene_num = matches[0]
    start = REALESTATE_SCENES[scene_num][1]
    db = root / REALESTATE_DB
    if not (db / "train_test_sets").is_dir():
        repo.copy_tree(f"{REALESTATE_DB}/train_test_sets", root)
    out = db / f"test/database_data/{scene_num:05}"
    (out / "rgb").mkdir(parents=True, exist_ok=True)
    fields = read_realestate_camera_lines(scene_dir / f"{video}.txt")
    first = int(np.where(fields[:, 0].astype(int) == start)[0][0])
    frames = fields[first:first + CLIP_LENGTH]
    assert len(frames) == CLIP_LENGTH, f"{video}: {len(frames)} lines from timestamp {start}, need {CLIP_LENGTH}"
    for i, timestamp in enumerate(frames[:, 0]):
        _write_png(scene_dir / f"frames/{timestamp}.png", out / f"rgb/{i:04}.png")
    import skimage.io

    height, width = skimage.io.imread(str(out / "rgb/0000.png")).shape[:2]
    extractor = repo.import_module("database_utils.real_estate.data_organizers.DataExtractor01").DataExtractor
    extrinsics = extractor.compute_extrinsic_matrices(frames[:, 7:19])  # [50, 16] float32, as the release writes
    intrinsics = extractor.compute_intrinsic_matrices(None, frames[:, 1:5], (height, width))  # [50, 9] float32
    np.savetxt(out / "CameraExtrinsics.csv", extrinsics, delimiter=",")
    np.savetxt(out / "CameraIntrinsics.csv", intrinsics, delimiter=",")
    return {"scene_num": scene_num, "w2c": extrinsics.astype(np.float64).reshape(-1, 4, 4),
            "intrinsics": intrinsics.astype(np.float64).reshape(-1, 3, 3), "height": height, "width": width,
            "db": db, "first_line": first}


def write_sparse_depth_csvs(folder: Path, per_frame: dict[int, pd.DataFrame]) -> None:
    """One `NNNN.csv` (x, y, depth, reprojection_error, weight) per frame number, as the release's sparse-depth
    generator (prior_generators/sparse_depth/Tester01.py, compute_colmap_depth) writes them."""
    folder.mkdir(parents=True, exist_ok=True)
    for frame_num, table in per_frame.items():
        table.to_csv(folder / f"{frame_num:04}.csv", index=False)
