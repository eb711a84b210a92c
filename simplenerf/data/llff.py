"""LLFF scenes (`nerf_llff_data/<scene>/{images_N, poses_bounds.npy}`): loading, the paper's split, the data module.

Split (the release's src/database_utils/nerf_llff/train_test_creators/TrainTestCreator01_UniformSparseSampling.py;
supplement, Database Details): test = every 8th frame; train = round(linspace(-1, N, n + 2))[1:-1] indexing the N
non-test frames; validation = the middle test frame. n_views None is the dense split of the reference NeRF (the
release's train set 1, num_train_frames -1): every non-test
frame trains. LLFF's test set does not depend on n, so one dense NeRF per scene serves every view count.
Bounds come from the train frames only; the scene is scaled by 1 / (0.75 * min bound) so the NDC near plane 1 lies
in front of every train camera, and recentred on the average train pose.

Reference depth (for depth metrics and visibility masks) is camera z-depth in FILE units (the units of the scene's
own poses, before scaling), one `<frame name>.npy` [H, W] per frame: the exact depth of the synthetic scene
(`depths_{factor}/`) or a dense NeRF's export (`evaluation.reference_depth`). File units make it independent of the
split, whose train bounds set the scale; loading multiplies by the scale.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import torch
from jsonargparse.typing import NonNegativeInt, PositiveInt

from simplenerf.data.scene import Scene, SceneDataModule, Split, explicit_split
from simplenerf.errors import DataError, absent
from simplenerf.geometry.poses import average_pose, poses_to_opengl, recenter
from simplenerf.geometry.views import Views

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def llff_split(
    num_frames: int, n_views: int | None, test_every: int = 8, train_frames: list[int] | None = None
) -> Split:
    """The paper's LLFF split for a scene of `num_frames` frames and `n_views` training views (None: every non-test
    frame, the dense reference NeRF's split), or the explicit `train_frames`. test_every 0: no test frames."""
    test = list(range(0, num_frames, test_every)) if test_every > 0 else []
    if train_frames is not None:
        return explicit_split(num_frames, train_frames, test)
    if not test:
        raise DataError("test_every 0 (no test frames) needs an explicit train_frames list")
    pool = [i for i in range(num_frames) if i not in test]
    if n_views is None:
        if not pool:
            raise DataError(f"a scene of {num_frames} frames has no non-test frame to train on")
        return Split(train=pool, test=test, val=[test[len(test) // 2]])
    if not 1 <= n_views <= len(pool):
        raise DataError(f"n_views={n_views} is not possible: the train pool has {len(pool)} frames")
    picks = np.round(np.linspace(-1, len(pool), n_views + 2))[1:-1].astype(int)
    return Split(train=[pool[i] for i in picks], test=test, val=[test[len(test) // 2]])


def read_image(path: Path) -> np.ndarray:
    """An 8-bit RGB image [H, W, 3]; a clear DataError if the file cannot be decoded."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DataError(f"cannot read image {path} (missing, truncated or not an image)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_same_size_images(paths: list[Path]) -> list[np.ndarray]:
    """Every image of `paths` ([H, W, 3] uint8); DataError naming the first whose size differs from the first's."""
    images = []
    for path in paths:
        image = read_image(path)
        if images and image.shape != images[0].shape:
            (h, w), (h0, w0) = image.shape[:2], images[0].shape[:2]
            raise DataError(f"{path} is {w}x{h} but {paths[0].name} is {w0}x{h0}: all images must have the same size")
        images.append(image)
    return images


def natural_key(name: str) -> list[int | str]:
    """Sort key that orders the numbers inside a name by value: img2 before img10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def list_images(directory: Path) -> list[Path]:
    """The images of a folder in name order, which is the order of the rows of poses_bounds.npy.

    Raises DataError when names sort differently as text and by their numbers (img10 before img2 as text): which
    pose belongs to which image would then be a guess.
    """
    paths = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    by_number = sorted(paths, key=lambda p: natural_key(p.name))
    for text, number in zip(paths, by_number, strict=True):
        if text != number:
            raise DataError(
                f"{directory}: image names sort differently as text and by number (as text {text.name} comes before "
                f"{number.name}), so which pose of poses_bounds.npy belongs to which image is ambiguous; rename them "
                "with zero-padded numbers (e.g. img002.png)"
            )
    return paths


def image_dir(scene_dir: Path, factor: int) -> Path:
    return scene_dir / ("images" if factor == 1 else f"images_{factor}")


def check_scene(scene_dir: Path, factor: int) -> tuple[list[Path], np.ndarray]:
    """Checks the files of a scene without decoding images; returns the image paths and the poses_bounds array."""
    if not scene_dir.is_dir():
        raise DataError(f"scene directory {scene_dir} {absent(scene_dir, folder=True)}")
    poses_file = scene_dir / "poses_bounds.npy"
    if not poses_file.is_file():
        raise DataError(f"{poses_file} is missing (LLFF layout: <scene>/poses_bounds.npy and <scene>/images_N/)")
    images = image_dir(scene_dir, factor)
    if not images.is_dir():
        have = sorted(p.name for p in scene_dir.iterdir() if p.is_dir() and p.name.startswith("images"))
        raise DataError(f"{images} is missing (factor={factor}); this scene has: {', '.join(have) or 'no images_*'}")
    paths = list_images(images)
    try:
        poses_bounds = np.load(poses_file)
    except (OSError, ValueError) as e:
        raise DataError(f"cannot read {poses_file}: {e}") from e
    if poses_bounds.ndim != 2 or poses_bounds.shape[1] != 17:
        raise DataError(f"{poses_file} has shape {poses_bounds.shape}, expected [num_frames, 17]")
    if len(paths) != len(poses_bounds):
        raise DataError(f"{images} has {len(paths)} images but {poses_file} has {len(poses_bounds)} poses")
    check_poses_bounds(poses_bounds, poses_file, [p.name for p in paths])
    return paths, poses_bounds


def check_poses_bounds(poses_bounds: np.ndarray, source: Path, names: list[str]) -> None:
    """DataError naming `source` and the first bad frame: a non-finite number, a non-positive image size or focal
    length, or bounds that are not 0 < near < far. `names` [N] name the frames (their image files)."""
    mats = poses_bounds[:, :15].reshape(-1, 3, 5)
    for i, (row, name) in enumerate(zip(poses_bounds, names, strict=True)):
        where = f"{source}: frame {i} ({name})"
        if not np.all(np.isfinite(row)):
            raise DataError(f"{where} has a non-finite value: {np.array2string(row, precision=4, separator=', ')}")
        if not np.all(mats[i, :, 4] > 0):
            raise DataError(f"{where} has height, width, focal {mats[i, :, 4].tolist()}; all must be positive")
        near, far = row[15:17]
        if not 0 < near < far:
            raise DataError(f"{where} has near bound {near:g} and far bound {far:g}; they must be 0 < near < far")


def read_reference_depth(directory: str | Path, names: list[str], height: int, width: int) -> np.ndarray:
    """Reference depth [V, H, W] in file units from `<directory>/<name>.npy` for each frame name, checked."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"reference depth folder {directory} {absent(directory, folder=True)}")
    depths = []
    for name in names:
        path = directory / f"{name}.npy"
        if not path.is_file():
            raise DataError(f"{path} is missing: the reference depth folder needs one <frame name>.npy per frame")
        try:
            depth = np.load(path)
        except (OSError, ValueError) as e:
            raise DataError(f"cannot read reference depth {path}: {e}") from e
        if depth.shape != (height, width):
            raise DataError(f"{path} has shape {depth.shape}, expected the frame's ({height}, {width})")
        depths.append(depth)
    return np.stack(depths)


def make_views(
    images: np.ndarray, intrinsics: np.ndarray, c2w: np.ndarray, names: list[str], depths: np.ndarray | None,
    scale: float,
) -> Views:
    """Views in the default dtype from uint8 images [V, H, W, 3], cameras and file-unit depths [V, H, W] (or None)."""
    dtype = torch.get_default_dtype()
    return Views(
        images=torch.from_numpy(images).to(dtype) / 255.0,
        intrinsics=torch.from_numpy(intrinsics).to(dtype),
        c2w=torch.from_numpy(c2w).to(dtype),
        names=names,
        depths=None if depths is None else torch.from_numpy(depths * scale).to(dtype),
    )


def load_llff_scene(
    scene_dir: str | Path, factor: int, n_views: int | None, test_every: int = 8,
    reference_depth_dir: str | Path | None = None, train_frames: list[int] | None = None,
) -> Scene:
    """Reads every frame of an LLFF scene at `images_{factor}`, with reference depth from `reference_depth_dir` if
    given, else from `depths_{factor}/` if present."""
    scene_dir = Path(scene_dir)
    paths, poses_bounds = check_scene(scene_dir, factor)
    split = llff_split(len(paths), n_views, test_every, train_frames)
    images = np.stack(read_same_size_images(paths))
    height, width = images.shape[1:3]

    c2w, hwf, bounds = poses_to_opengl(poses_bounds)
    scale = 1.0 / (0.75 * bounds[split.train].min())
    c2w[:, :, 3] *= scale
    c2w = recenter(c2w, average_pose(c2w[split.train]))
    focal = hwf[:, 2] * width / hwf[:, 1]
    intrinsics = np.zeros((len(paths), 3, 3))
    intrinsics[:, 0, 0], intrinsics[:, 1, 1] = focal, focal
    intrinsics[:, 0, 2], intrinsics[:, 1, 2], intrinsics[:, 2, 2] = width / 2, height / 2, 1.0

    names = [p.stem for p in paths]
    depths = None
    depth_dir = scene_dir / image_dir(scene_dir, factor).name.replace("images", "depths")
    if reference_depth_dir is not None:
        depths = read_reference_depth(reference_depth_dir, names, height, width)
    elif depth_dir.is_dir():
        depths = read_reference_depth(depth_dir, names, height, width)
    views = make_views(images, intrinsics, c2w, names, depths, scale)
    return Scene(views=views, split=split, scale=scale, bounds=bounds * scale, source=scene_dir,
                 file_cameras=np.asarray(poses_bounds))


def subset(views: Views, indices: list[int]) -> Views:
    """The views at `indices` (`Views.subset`)."""
    return views.subset(indices)


class LLFFDataModule(SceneDataModule):
    """An LLFF-layout scene (`poses_bounds.npy`, `images_N/`); rays, splits and sparse depth: `SceneDataModule`."""

    def __init__(self, scene_dir: str, factor: PositiveInt = 4, test_every: NonNegativeInt = 8, **kwargs) -> None:
        """
        Args:
            scene_dir: the scene folder, e.g. data/nerf_llff_data/fern (holds poses_bounds.npy and images_N/).
            factor: image downsampling factor: reads images_{factor}/ (1 reads images/); the paper uses 4.
            test_every: every this-many-th frame is a test frame (the paper: 8); 0: no test frames (own photos).
        """
        super().__init__(**kwargs)
        self.scene_dir, self.factor, self.test_every = Path(scene_dir), factor, test_every

    def cache_key(self) -> dict:
        return {**super().cache_key(), "factor": self.factor}

    def load_scene(self) -> Scene:
        return load_llff_scene(self.scene_dir, self.factor, self.n_views, self.test_every, self.reference_depth_dir,
                               self.train_frames)
