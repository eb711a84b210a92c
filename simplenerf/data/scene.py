"""What every scene format shares: the split, the `Scene` it loads, and the `SceneDataModule` base.

A format (LLFF, RealEstate-10K, the synthetic scene) declares only its own arguments and `load_scene`; the base owns
the rest: which frames train (`n_views` by the paper's split, or an explicit `train_frames` list), random training
rays, sparse depth (SfM on the train views), reference depth, and the full frames of validation, test and predict.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import numpy as np
import torch
from jsonargparse.typing import NonNegativeInt, PositiveInt
from torch.utils.data import DataLoader

from simplenerf.data.datasets import Frames, RandomRays, SparseDepthPool, unseen_patch_problem
from simplenerf.errors import DataError
from simplenerf.geometry.trajectories import TrajectoryKind, llff_spiral, recorded_trajectory
from simplenerf.geometry.views import Views
from simplenerf.metrics.duplicates import describe_duplicates, near_duplicates, thumbnail
from simplenerf.sfm.sparse_depth import load_or_compute_sparse_depth


@dataclass
class Split:
    """Frame indices (into the scene's sorted frames) of each role."""

    train: list[int]
    test: list[int]
    val: list[int]


def explicit_split(num_frames: int, train_frames: list[int], test: list[int]) -> Split:
    """The split with `train_frames` training and the format's `test` frames (minus any train frame) testing.

    Without test frames (own photos) the validation view is the first train frame.
    """
    bad = [i for i in train_frames if not 0 <= i < num_frames]
    if bad or not train_frames or len(set(train_frames)) != len(train_frames):
        raise DataError(f"train_frames {train_frames} must be distinct frame indices in [0, {num_frames - 1}]")
    train = sorted(train_frames)
    test = [i for i in test if i not in train]
    return Split(train=train, test=test, val=[test[len(test) // 2]] if test else [train[0]])


@dataclass
class Scene:
    """All frames of a scene, scaled and recentred, with the split, where it was read from and its video path."""

    views: Views
    split: Split
    scale: float  # scene units per file unit
    bounds: np.ndarray  # [N, 2] near/far per frame, scene units
    source: Path  # the folder the scene was read from (its name names the scene in results)
    camera_path: TrajectoryKind = "spiral"  # the format's video path: LLFF's spiral, or a clip's own ("recorded")
    file_cameras: np.ndarray | None = None
    """The frames' cameras as the scene's files give them (before scaling and recentring on the train views): what
    identifies the scene's poses whatever the split (`run.resume.scene_digest`); None: not given by the format."""

    def trajectory(
        self, kind: TrajectoryKind | None = None, n_frames: int = 120, n_rotations: float = 2
    ) -> torch.Tensor:
        """The video path of the scene (`kind`, None: `camera_path`): the spiral fitted to ALL its frames' poses and
        bounds, or the recorded path of all its frames (n_frames and n_rotations are then unused). Returns c2w
        [N, 3, 4].

        The spiral follows the authors' release, which fits it to every frame of the scene, train and test: with 2
        train views the 90th-percentile radii of the train poses alone are those of the two cameras, so the path
        would shrink to (nearly) a line between them. A scene of one's own photos without other frames has only its
        train views, which are then all there is to fit to.
        """
        kind = kind or self.camera_path
        if kind == "spiral":
            return llff_spiral(self.views.c2w, self.bounds, n_frames, n_rotations)
        if kind == "recorded":
            return recorded_trajectory(self.views)
        raise ValueError(f"unknown trajectory {kind!r}: expected 'spiral' or 'recorded'")


class SceneDataModule(L.LightningDataModule, abc.ABC):
    """Random training rays from the train views, full frames for validation, test and predict."""

    def __init__(
        self,
        n_views: PositiveInt | None = 2,
        train_frames: list[NonNegativeInt] | None = None,
        rays_per_batch: PositiveInt = 2048,
        near: float = 1.0,
        seed: int = 0,
        num_workers: NonNegativeInt = 0,
        sparse_rays_per_batch: NonNegativeInt = 0,
        sparse_depth_cache: str = "data/cache/sparse_depth",
        sparse_depth_weighting: bool = False,
        reference_depth_dir: str | None = None,
        unseen_patches_per_batch: NonNegativeInt = 0,
        unseen_patch_size: PositiveInt = 8,
        unseen_spread: float = 1.0,
    ) -> None:
        """
        Args:
            n_views: number of training views by the paper's split of the format (2, 3 or 4 in the paper); null:
                every non-test frame (the dense reference NeRF, configs/dense/).
            train_frames: explicit training frames (indices into the scene's sorted frames), instead of n_views;
                test frames are then the format's test frames that do not train (none: `test` renders only).
            rays_per_batch: random training rays per iteration.
            near: NDC near plane in scaled scene units (the model's `nerf.near` is linked to it).
            seed: seed of the training-ray order.
            num_workers: data-loader worker processes for training rays.
            sparse_rays_per_batch: rays per iteration at pixels with an SfM depth, for the sparse-depth loss
                (DS-NeRF / SimpleNeRF: 2048); 0 disables sparse depth.
            sparse_depth_cache: folder where the sparse depth of a scene, view set and resolution is cached.
            sparse_depth_weighting: weight each point by DS-NeRF's 2 exp(-(err / mean err)^2) of its reprojection
                error (off in DS-NeRF's and SimpleNeRF's releases).
            reference_depth_dir: folder of reference depth `<frame name>.npy` (camera z-depth in file units, e.g. a
                dense NeRF's export by `simplenerf export-depth`) for depth metrics and visibility masks;
                null: the format's own (the synthetic scene's exact depth), else no depth metrics.
            unseen_patches_per_batch: square patches per iteration from cameras no train view has, for the depth
                smoothness prior (`model.objective.depth_smoothness_weight`; RegNeRF's unobserved views); 0: none.
                Not in the paper.
            unseen_patch_size: their side in pixels (RegNeRF: 8).
            unseen_spread: how far the unseen cameras leave the train centres' hull, in mean distances between
                neighbouring train centres (`geometry.unseen.unseen_cameras`).
        """
        super().__init__()
        self.n_views, self.train_frames = n_views, None if train_frames is None else list(train_frames)
        self.rays_per_batch, self.near, self.seed, self.num_workers = rays_per_batch, near, seed, num_workers
        self.sparse_rays_per_batch, self.sparse_depth_cache = sparse_rays_per_batch, sparse_depth_cache
        self.sparse_depth_weighting = sparse_depth_weighting
        self.reference_depth_dir = reference_depth_dir
        self.unseen_patches_per_batch, self.unseen_patch_size = unseen_patches_per_batch, unseen_patch_size
        self.unseen_spread = unseen_spread
        self.scene: Scene | None = None
        self.sparse_depth: SparseDepthPool | None = None

    @abc.abstractmethod
    def load_scene(self) -> Scene:
        """All frames of the scene with the split (of `n_views`, or of `train_frames` when given)."""

    def cache_key(self) -> dict:
        """The scene's folder and loading settings, as a run records them (`run.resume`); the sparse-depth cache uses
        them without the folder, beside the train views, the resolution and a fingerprint of the images and cameras."""
        assert self.scene is not None, "call setup() first"
        return {"scene": str(self.scene.source.resolve())}

    def check_inputs(self, stage: str) -> None:
        """Loads everything `stage` needs; the CLI calls this before loggers or outputs start, so bad input (a missing
        or unreadable file, an impossible split, a scene without SfM points) stops the run with nothing written."""
        if self.scene is None:
            self.scene = self.load_scene()
        if stage == "fit":  # checked here (before SfM), not when the first batch is drawn inside Lightning
            train = self.train_views
            pixels = len(train) * train.height * train.width
            if self.rays_per_batch > pixels:
                raise DataError(
                    f"--data.init_args.rays_per_batch: {self.rays_per_batch} is more than the {pixels} training pixels "
                    f"({len(train)} train views of {train.width}x{train.height}); use at most {pixels}"
                )
            if self.unseen_patches_per_batch and (problem := unseen_patch_problem(train, self.unseen_patch_size)):
                raise DataError(f"--data.init_args.unseen_patches_per_batch: {problem}")
            images = train.images.detach().cpu().float().numpy()
            if same := near_duplicates([thumbnail(image) for image in images], list(train.names)):
                raise DataError(
                    f"train images {describe_duplicates(same)} of {self.scene.source} are identical or nearly (mean "
                    "difference under 2/255): a NeRF needs views from different positions; check the scene's images "
                    "(a copied file?), or choose other train frames (--data.init_args.train_frames)"
                )
        self.setup(stage)

    def setup(self, stage: str) -> None:
        if self.scene is None:
            self.scene = self.load_scene()
        if stage == "fit" and self.sparse_rays_per_batch and self.sparse_depth is None:
            self.sparse_depth = self.load_sparse_depth()

    def load_sparse_depth(self) -> SparseDepthPool:
        """SfM depth of the train views (poses fixed), computed with pycolmap on first use and cached."""
        train = self.train_views
        # Not keyed by the folder: the cache's fingerprint of the images and cameras identifies the scene, so a moved
        # or copied scene reuses its SfM result.
        key = {**{k: v for k, v in self.cache_key().items() if k != "scene"}, "views": self.scene.split.train,
               "height": train.height, "width": train.width}
        print(f"sparse depth: SfM on train views {self.scene.split.train} of {self.scene.source} "
              f"(cached in {self.sparse_depth_cache}) ...", flush=True)
        per_view = load_or_compute_sparse_depth(self.sparse_depth_cache, key, train.images, train.intrinsics,
                                                train.c2w, image_names=list(train.names))
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
        return self.scene.views.subset(self.scene.split.train)

    def train_dataloader(self) -> DataLoader:
        # A resumed fit continues the ray order after the batches its steps have drawn (one per optimiser step and
        # gradient-accumulation batch), instead of replaying it from the first.
        trainer = self.trainer
        drawn = trainer.global_step * trainer.accumulate_grad_batches if trainer is not None else 0
        rays = RandomRays(self.train_views, self.rays_per_batch, self.near, self.seed, self.sparse_depth,
                          self.sparse_rays_per_batch, start_batch=drawn, unseen_patches=self.unseen_patches_per_batch,
                          patch_size=self.unseen_patch_size, unseen_spread=self.unseen_spread)
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
