"""RealEstate-10K clips (`<id>/{<id>.txt, frames/<timestamp>.png}`): the camera file, the paper's split, the module.

The camera file is the dataset's own: line 1 is the video URL, then one line per frame,
`timestamp fx fy cx cy k1 k2 r11 r12 r13 t1 r21 r22 r23 t2 r31 r32 r33 t3` (k1 = k2 = 0): intrinsics normalised by
the image width (fx, cx) and height (fy, cy), and a row-major 3x4 WORLD-TO-CAMERA matrix in OpenCV axes (x right,
y down, z forward). Frame `timestamp` is `frames/<timestamp>.png` at any resolution (sizes are read from the images).
The paper uses 50 consecutive frames per video at 1024x576, bounds fixed to [1, 100] in file units.

Split (the supplement's Table "Train and test frame numbers"; the release's src/database_utils/real_estate/
train_test_creators/TrainTestCreator01.py), frame numbers within the clip:
train 2 views {10, 20}, 3 views {10, 20, 30}, 4 views {0, 10, 20, 30}; test = every frame in
[min train - 5, max train + 5] that lies in the clip and is not a train frame (19 / 28 / 32 frames); validation = the
middle test frame. The test set depends on the view count, so the dense reference NeRF (n_views None) is trained on
every clip frame outside the test set of `split_views` views: the reference for n views is the one trained with
split_views = n.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from jsonargparse.typing import NonNegativeInt, PositiveInt

from simplenerf.data.llff import (
    IMAGE_SUFFIXES,
    make_views,
    read_reference_depth,
    read_same_size_images,
)
from simplenerf.data.scene import Scene, SceneDataModule, Split, explicit_split
from simplenerf.errors import DataError, absent
from simplenerf.geometry.poses import average_pose, recenter

# The paper's train frames in order of use: the first n train the n-view model.
TRAIN_ORDER = (10, 20, 30, 0, 40)
EXTRAPOLATION_FRAMES = 5  # test frames on either side of the train frames
BOUNDS = (1.0, 100.0)  # near / far in file units, fixed as in the paper (ViP-NeRF's setting)
FIELDS_PER_LINE = 19  # timestamp, fx fy cx cy, two zeros, a 3x4 matrix


def realestate_split(
    n_views: int | None, clip_length: int = 50, split_views: int = 2, train_frames: list[int] | None = None
) -> Split:
    """The paper's split of a clip of `clip_length` frames for `n_views` training views (2, 3 or 4).

    n_views None is the dense split: train = every frame not in the test set of the `split_views`-view split.
    Explicit `train_frames` train instead, tested on the `split_views` split's test frames that do not train.
    """
    if train_frames is not None:
        return explicit_split(clip_length, train_frames, realestate_split(split_views, clip_length).test)
    if n_views is None:
        sparse = realestate_split(split_views, clip_length)
        test = set(sparse.test)
        return Split(train=[i for i in range(clip_length) if i not in test], test=sparse.test, val=sparse.val)
    if n_views not in (2, 3, 4):
        raise DataError(f"n_views={n_views} is not possible on RealEstate-10K: the paper's splits have 2, 3 or 4 views")
    train = sorted(TRAIN_ORDER[:n_views])
    if train[-1] >= clip_length:
        raise DataError(f"clip_length={clip_length} is too short for {n_views} views: frame {train[-1]} trains")
    lo, hi = max(train[0] - EXTRAPOLATION_FRAMES, 0), min(train[-1] + EXTRAPOLATION_FRAMES, clip_length - 1)
    test = [i for i in range(lo, hi + 1) if i not in train]
    return Split(train=train, test=test, val=[test[len(test) // 2]])


def read_camera_file(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Parses a RealEstate-10K camera file.

    Returns:
        timestamps [N] (as written, they name the frame files), normalised intrinsics [N, 4] (fx, fy, cx, cy),
        world-to-camera matrices [N, 3, 4] (OpenCV axes), all float64.
    """
    if not path.is_file():
        raise DataError(f"camera file {path} is missing (RealEstate-10K layout: <id>/<id>.txt and <id>/frames/)")
    lines = path.read_text().splitlines()
    timestamps, numbers = [], []
    for number, line in enumerate(lines[1:], start=2):  # line 1 is the video URL
        fields = line.split()
        if not fields:
            continue
        if len(fields) != FIELDS_PER_LINE:
            raise DataError(
                f"{path} line {number}: expected {FIELDS_PER_LINE} fields (timestamp fx fy cx cy 0 0 and a row-major "
                f"3x4 world-to-camera matrix), got {len(fields)}"
            )
        try:
            values = [float(f) for f in fields[1:]]
        except ValueError as e:
            raise DataError(f"{path} line {number}: expected numbers after the timestamp ({e})") from e
        if not fields[0].isdigit():
            raise DataError(f"{path} line {number}: expected an integer timestamp first, got {fields[0]!r}")
        if not all(np.isfinite(values)):
            raise DataError(f"{path} line {number} (frame {fields[0]}): the camera has a non-finite value")
        if not all(v > 0 for v in values[:2]):
            raise DataError(f"{path} line {number} (frame {fields[0]}): focal lengths fx fy must be positive")
        timestamps.append(fields[0])
        numbers.append(values)
    if not numbers:
        raise DataError(f"{path} has no camera lines (expected the video URL, then one line per frame)")
    array = np.array(numbers, dtype=np.float64)
    return timestamps, array[:, :4], array[:, 6:].reshape(-1, 3, 4)


def opencv_w2c_to_opengl_c2w(w2c: np.ndarray) -> np.ndarray:
    """Camera-to-world [N, 3, 4] in OpenGL axes (right, up, back) from world-to-camera [N, 3, 4] in OpenCV axes."""
    rotation, translation = w2c[:, :, :3], w2c[:, :, 3]
    rotation_c2w = rotation.transpose(0, 2, 1)
    centre = -(rotation_c2w @ translation[:, :, None])[:, :, 0]
    # OpenCV's camera y (down) and z (forward) are OpenGL's -up and -back.
    return np.concatenate([rotation_c2w * np.array([1.0, -1.0, -1.0]), centre[:, :, None]], axis=-1)


def pixel_intrinsics(normalised: np.ndarray, height: int, width: int) -> np.ndarray:
    """Intrinsic matrices [N, 3, 3] in pixels from normalised (fx, fy, cx, cy) [N, 4]."""
    fx, fy, cx, cy = normalised.T
    intrinsics = np.zeros((len(normalised), 3, 3))
    intrinsics[:, 0, 0], intrinsics[:, 1, 1] = fx * width, fy * height
    intrinsics[:, 0, 2], intrinsics[:, 1, 2], intrinsics[:, 2, 2] = cx * width, cy * height, 1.0
    return intrinsics


def frame_path(frames_dir: Path, timestamp: str) -> Path | None:
    """`frames/<timestamp>.png` (or another image suffix), None if there is none."""
    for suffix in IMAGE_SUFFIXES:
        path = frames_dir / f"{timestamp}{suffix}"
        if path.is_file():
            return path
    return None


def load_realestate_scene(
    scene_dir: str | Path, n_views: int | None, clip_start: int = 0, clip_length: int = 50, split_views: int = 2,
    reference_depth_dir: str | Path | None = None, train_frames: list[int] | None = None,
) -> Scene:
    """Reads the clip of `clip_length` frames from line `clip_start` of the camera file, scaled and recentred."""
    scene_dir = Path(scene_dir)
    if not scene_dir.is_dir():
        raise DataError(f"scene directory {scene_dir} {absent(scene_dir, folder=True)}")
    camera_file = scene_dir / f"{scene_dir.name}.txt"
    frames_dir = scene_dir / "frames"
    timestamps, normalised, w2c = read_camera_file(camera_file)
    if not frames_dir.is_dir():
        raise DataError(f"frames folder {frames_dir} is missing (RealEstate-10K layout: <id>/frames/<timestamp>.png)")
    if clip_start < 0 or clip_length < 1 or clip_start + clip_length > len(timestamps):
        raise DataError(f"{camera_file} has {len(timestamps)} frames; the clip needs frames {clip_start} to "
                        f"{clip_start + clip_length - 1} (clip_start={clip_start}, clip_length={clip_length})")
    split = realestate_split(n_views, clip_length, split_views, train_frames)
    clip = slice(clip_start, clip_start + clip_length)
    timestamps, normalised, w2c = timestamps[clip], normalised[clip], w2c[clip]
    paths = []
    for timestamp in timestamps:
        path = frame_path(frames_dir, timestamp)
        if path is None:
            raise DataError(f"{frames_dir} has no frame {timestamp}.png for timestamp {timestamp} of {camera_file}")
        paths.append(path)
    images = np.stack(read_same_size_images(paths))
    height, width = images.shape[1:3]

    scale = 1.0 / (0.75 * BOUNDS[0])  # as LLFF: the near bound lands at 4/3, in front of the NDC near plane 1
    c2w = opencv_w2c_to_opengl_c2w(w2c)
    c2w[:, :, 3] *= scale
    c2w = recenter(c2w, average_pose(c2w[split.train]))
    depths = None
    if reference_depth_dir is not None:
        depths = read_reference_depth(reference_depth_dir, timestamps, height, width)
    views = make_views(images, pixel_intrinsics(normalised, height, width), c2w, timestamps, depths, scale)
    bounds = np.tile(np.array(BOUNDS) * scale, (clip_length, 1))
    return Scene(views=views, split=split, scale=scale, bounds=bounds, source=scene_dir, camera_path="recorded",
                 file_cameras=np.concatenate([np.asarray(normalised), np.asarray(w2c).reshape(clip_length, -1)], 1))


class RealEstateDataModule(SceneDataModule):
    """A RealEstate-10K clip with the paper's split; rays, sparse depth and frames work as for LLFF.

    Note: in this project's copy of scene 000c3ab189999a83 (256x256 centre crops, intrinsics adjusted), 18 of the 50
    frames repeat the previous frame because the source video has fewer frames than camera timestamps, so those
    images lag their pose by one frame. That is the data as distributed; it is read as is.
    """

    def __init__(
        self, scene_dir: str, clip_start: NonNegativeInt = 0, clip_length: PositiveInt = 50,
        split_views: PositiveInt = 2, **kwargs,
    ) -> None:
        """
        Args:
            scene_dir: the video's folder, e.g. data/realestate10k/000c3ab189999a83 (holds <id>.txt and frames/).
                n_views 2, 3, 4 train frames {10, 20}, {10, 20, 30}, {0, 10, 20, 30} of the clip; null: every clip
                frame outside the test set of `split_views` views (the dense reference NeRF).
            clip_start: index of the clip's first frame among the camera file's frame lines.
            clip_length: number of consecutive frames in the clip (50 in the paper).
            split_views: with n_views null, whose test frames are held out: the dense reference for the n-view
                evaluation is the one trained with split_views n (the test set depends on the view count).
        """
        super().__init__(**kwargs)
        self.scene_dir = Path(scene_dir)
        self.clip_start, self.clip_length, self.split_views = clip_start, clip_length, split_views

    def load_scene(self) -> Scene:
        return load_realestate_scene(self.scene_dir, self.n_views, self.clip_start, self.clip_length,
                                     self.split_views, self.reference_depth_dir, self.train_frames)
