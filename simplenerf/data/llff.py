"""LLFF scenes (`nerf_llff_data/<scene>/{images_N, poses_bounds.npy}`): loading, the paper's split, the data module.

Split (SPEC 6): test = every 8th frame; train = round(linspace(-1, N, n + 2))[1:-1] indexing the N non-test frames;
validation = the middle test frame. n_views None is the dense split of the reference NeRF (SPEC 7): every non-test
frame trains. LLFF's test set does not depend on n, so one dense NeRF per scene serves every view count.
Bounds come from the train frames only; the scene is scaled by 1 / (0.75 * min bound) so the NDC near plane 1 lies
in front of every train camera, and recentred on the average train pose.

Reference depth (for depth metrics and visibility masks) is camera z-depth in FILE units (the units of the scene's
own poses, before scaling), one `<frame name>.npy` [H, W] per frame: the exact depth of the synthetic scene
(`depths_{factor}/`) or a dense NeRF's export (`evaluation.reference_depth`). File units make it independent of the
split, whose train bounds set the scale; loading multiplies by the scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from simplenerf.data.datasets import Frames, RandomRays, SparseDepthPool, Views
from simplenerf.data.sparse_depth import load_or_compute_sparse_depth
from simplenerf.errors import DataError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass
class Split:
    """Frame indices (into the scene's sorted frames) of each role."""

    train: list[int]
    test: list[int]
    val: list[int]


def llff_split(num_frames: int, n_views: int | None, test_every: int = 8) -> Split:
    """The paper's LLFF split for a scene of `num_frames` frames and `n_views` training views (None: every non-test
    frame, the dense reference NeRF's split)."""
    test = list(range(0, num_frames, test_every))
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


def list_images(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def poses_to_opengl(poses_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Splits LLFF's [N, 17] rows into c2w [N, 3, 4] (OpenGL axes), hwf [N, 3] and bounds [N, 2].

    LLFF stores the rotation columns as [down, right, back]; OpenGL's are [right, up, back].
    """
    mats = poses_bounds[:, :15].reshape(-1, 3, 5)
    down, right, back, centre = mats[:, :, 0], mats[:, :, 1], mats[:, :, 2], mats[:, :, 3]
    c2w = np.stack([right, -down, back, centre], axis=-1)
    return c2w, mats[:, :, 4], poses_bounds[:, 15:17]


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def average_pose(c2w: np.ndarray) -> np.ndarray:
    """The mean camera [3, 4]: mean centre, mean viewing axis, mean up vector (orthonormalised)."""
    centre = c2w[:, :, 3].mean(0)
    back = _normalize(c2w[:, :, 2].sum(0))
    right = _normalize(np.cross(c2w[:, :, 1].sum(0), back))
    up = np.cross(back, right)
    return np.stack([right, up, back, centre], axis=-1)


def recenter(c2w: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Expresses poses [N, 3, 4] in the frame of `reference` [3, 4]."""
    to_h = np.array([[0.0, 0.0, 0.0, 1.0]])
    ref_inv = np.linalg.inv(np.concatenate([reference, to_h]))
    return np.stack([(ref_inv @ np.concatenate([p, to_h]))[:3] for p in c2w])


@dataclass
class LLFFScene:
    """All frames of a scene, scaled and recentred, with the split."""

    views: Views
    split: Split
    scale: float  # scene units per file unit
    bounds: np.ndarray  # [N, 2] near/far per frame, scene units


def image_dir(scene_dir: Path, factor: int) -> Path:
    return scene_dir / ("images" if factor == 1 else f"images_{factor}")


def check_scene(scene_dir: Path, factor: int) -> tuple[list[Path], np.ndarray]:
    """Checks the files of a scene without decoding images; returns the image paths and the poses_bounds array."""
    if not scene_dir.is_dir():
        raise DataError(f"scene directory {scene_dir} does not exist")
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
    return paths, poses_bounds


def read_reference_depth(directory: str | Path, names: list[str], height: int, width: int) -> np.ndarray:
    """Reference depth [V, H, W] in file units from `<directory>/<name>.npy` for each frame name, checked."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"reference depth folder {directory} does not exist")
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
    reference_depth_dir: str | Path | None = None,
) -> LLFFScene:
    """Reads every frame of an LLFF scene at `images_{factor}`, with reference depth from `reference_depth_dir` if
    given, else from `depths_{factor}/` if present."""
    scene_dir = Path(scene_dir)
    paths, poses_bounds = check_scene(scene_dir, factor)
    split = llff_split(len(paths), n_views, test_every)
    images = np.stack([read_image(p) for p in paths])
    if len({im.shape for im in images}) > 1:
        raise DataError(f"images in {paths[0].parent} differ in size")
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
    return LLFFScene(views=views, split=split, scale=scale, bounds=bounds * scale)


def subset(views: Views, indices: list[int]) -> Views:
    """The views at `indices` (views of a scene -> views of one split)."""
    return Views(
        images=views.images[indices],
        intrinsics=views.intrinsics[indices],
        c2w=views.c2w[indices],
        names=[views.names[i] for i in indices],
        depths=None if views.depths is None else views.depths[indices],
    )


class LLFFDataModule(L.LightningDataModule):
    """An LLFF-layout scene: random training rays from the n train views, full validation and test frames."""

    def __init__(
        self,
        scene_dir: str,
        n_views: int | None = 2,
        factor: int = 4,
        rays_per_batch: int = 2048,
        test_every: int = 8,
        near: float = 1.0,
        seed: int = 0,
        num_workers: int = 0,
        sparse_rays_per_batch: int = 0,
        sparse_depth_cache: str = "data/cache/sparse_depth",
        sparse_depth_weighting: bool = False,
        reference_depth_dir: str | None = None,
    ) -> None:
        """
        Args:
            scene_dir: the scene folder, e.g. data/nerf_llff_data/fern (holds poses_bounds.npy and images_N/).
            n_views: number of training views (2, 3 or 4 in the paper); null: every non-test frame (the dense
                reference NeRF, configs/dense/).
            factor: image downsampling factor: reads images_{factor}/ (1 reads images/); the paper uses 4.
            rays_per_batch: random training rays per iteration.
            test_every: every this-many-th frame is a test frame.
            near: NDC near plane in scaled scene units.
            seed: seed of the training-ray order.
            num_workers: data-loader worker processes for training rays.
            sparse_rays_per_batch: rays per iteration at pixels with an SfM depth, for the sparse-depth loss
                (DS-NeRF / SimpleNeRF: 2048); 0 disables sparse depth.
            sparse_depth_cache: folder where the sparse depth of a scene, view set and resolution is cached.
            sparse_depth_weighting: weight each point by DS-NeRF's 2 exp(-(err / mean err)^2) of its reprojection
                error (off in DS-NeRF's and SimpleNeRF's releases).
            reference_depth_dir: folder of reference depth `<frame name>.npy` (camera z-depth in file units, e.g. a
                dense NeRF's export by tools/export_reference_depth.py) for depth metrics; null: `depths_{factor}/`
                next to the images if present (the synthetic scene's exact depth), else no depth metrics.
        """
        super().__init__()
        self.scene_dir, self.n_views, self.factor = Path(scene_dir), n_views, factor
        self.rays_per_batch, self.test_every, self.near = rays_per_batch, test_every, near
        self.seed, self.num_workers = seed, num_workers
        self.sparse_rays_per_batch, self.sparse_depth_cache = sparse_rays_per_batch, sparse_depth_cache
        self.sparse_depth_weighting = sparse_depth_weighting
        self.reference_depth_dir = reference_depth_dir
        self.scene: LLFFScene | None = None
        self.sparse_depth: SparseDepthPool | None = None

    def check_inputs(self, stage: str) -> None:
        """Loads everything `stage` needs; the CLI calls this before loggers or outputs start, so bad input (a missing
        or unreadable file, an impossible split, a scene without SfM points) stops the run with nothing written."""
        self.setup(stage)

    def load_scene(self) -> LLFFScene:
        """All frames of the scene with the split; subclasses for other formats override this alone."""
        return load_llff_scene(self.scene_dir, self.factor, self.n_views, self.test_every, self.reference_depth_dir)

    def setup(self, stage: str) -> None:
        if self.scene is None:
            self.scene = self.load_scene()
        if stage == "fit" and self.sparse_rays_per_batch and self.sparse_depth is None:
            self.sparse_depth = self.load_sparse_depth()

    def load_sparse_depth(self) -> SparseDepthPool:
        """SfM depth of the train views (poses fixed), computed with pycolmap on first use and cached."""
        train = self.train_views
        key = {"scene": str(self.scene_dir.resolve()), "views": self.scene.split.train, "factor": self.factor,
               "height": train.height, "width": train.width}
        print(f"sparse depth: SfM on train views {self.scene.split.train} of {self.scene_dir} "
              f"(cached in {self.sparse_depth_cache}) ...", flush=True)
        per_view = load_or_compute_sparse_depth(self.sparse_depth_cache, key, train.images, train.intrinsics,
                                                train.c2w)
        for i, sd in zip(self.scene.split.train, per_view, strict=True):
            print(f"  frame {i}: {len(sd)} points, median reprojection error "
                  f"{np.median(sd.reprojection_error):.2f} px", flush=True)
        dtype = train.images.dtype
        error = torch.from_numpy(np.concatenate([sd.reprojection_error for sd in per_view])).to(dtype)
        weight = torch.ones_like(error)
        if self.sparse_depth_weighting:
            weight = 2 * torch.exp(-((error / error.mean()) ** 2))
        return SparseDepthPool(
            view=torch.cat([torch.full((len(sd),), i) for i, sd in enumerate(per_view)]),
            uv=torch.from_numpy(np.concatenate([sd.pixels for sd in per_view])).to(dtype),
            depth=torch.from_numpy(np.concatenate([sd.depth for sd in per_view])).to(dtype),
            weight=weight,
        )

    @property
    def train_views(self) -> Views:
        assert self.scene is not None, "call setup() first"
        return subset(self.scene.views, self.scene.split.train)

    def train_dataloader(self) -> DataLoader:
        rays = RandomRays(self.train_views, self.rays_per_batch, self.near, self.seed, self.sparse_depth,
                          self.sparse_rays_per_batch)
        return DataLoader(rays, batch_size=None, num_workers=self.num_workers)

    def _frames(self, indices: list[int]) -> DataLoader:
        assert self.scene is not None, "call setup() first"
        return DataLoader(Frames(self.scene.views, self.near, indices), batch_size=None)

    def val_dataloader(self) -> DataLoader:
        return self._frames(self.scene.split.val)

    def test_dataloader(self) -> DataLoader:
        return self._frames(self.scene.split.test)

    def predict_dataloader(self) -> DataLoader:
        return self._frames(self.scene.split.test)
