"""Photos in: reading a user's photos (EXIF orientation and focal length), bringing them to one size, and
undistorting them to the pinhole camera with a centred principal point that the LLFF loader assumes."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pycolmap
from PIL import Image, ImageOps, UnidentifiedImageError

from simplenerf.errors import DataError, SfMError, absent
from simplenerf.sfm.mapping import ADVICE

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
_EXIF_IFD, _FOCAL_35MM, _FOCAL, _PLANE_X_RES, _PLANE_UNIT, _PIXEL_X = 0x8769, 0xA405, 0x920A, 0xA20E, 0xA210, 0xA002
_MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # FocalPlaneResolutionUnit: inch, cm, mm, um
_MAX_UNDISTORTION_SHIFT = 0.05  # pixels: below this everywhere, a photo is written as it is


# ----------------------------------------------------------------------------------------------------------------
# Photos in


@dataclass
class Photo:
    """One input photo after orientation, at its own size."""

    path: Path
    image: np.ndarray  # [H, W, 3] uint8 RGB, EXIF orientation applied
    focal: float | None  # EXIF focal length in pixels of `image`, or None


def find_photos(images_dir: Path) -> list[Path]:
    """The photos in a folder (by suffix, sorted); DataError if the folder is missing or has fewer than 2."""
    if not images_dir.is_dir():
        raise DataError(f"photo folder {images_dir} {absent(images_dir, folder=True)}")
    paths = sorted(p for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
    if len(paths) < 2:
        raise DataError(f"{images_dir} has {len(paths)} photos ({', '.join(PHOTO_SUFFIXES)}); at least 2 are needed. "
                        f"{ADVICE}")
    stems = Counter(p.stem for p in paths)
    clashes = sorted(s for s, n in stems.items() if n > 1)
    if clashes:
        raise DataError(f"{images_dir} has several photos named {', '.join(clashes)} (different suffixes); the "
                        f"output names them <name>.png, so rename them apart")
    return paths


def exif_focal_pixels(image: Image.Image) -> float | None:
    """Focal length in pixels of the image as stored, from EXIF: the 35 mm equivalent (over the diagonal, 43.27 mm),
    else the focal length in mm times the focal-plane resolution (scaled to this image's width); None if neither."""
    exif = image.getexif().get_ifd(_EXIF_IFD)
    width, height = image.size
    try:
        focal_35 = float(exif.get(_FOCAL_35MM) or 0)
        if focal_35 > 0:
            return focal_35 * math.hypot(width, height) / math.hypot(36.0, 24.0)
        focal_mm = float(exif.get(_FOCAL) or 0)
        resolution = float(exif.get(_PLANE_X_RES) or 0)
        mm_per_unit = _MM_PER_UNIT.get(int(exif.get(_PLANE_UNIT, 2)))
        if focal_mm > 0 and resolution > 0 and mm_per_unit:
            full_width = float(exif.get(_PIXEL_X) or width)
            return focal_mm * resolution / mm_per_unit * width / full_width
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return None


def read_photo(path: Path) -> Photo:
    """A photo as 8-bit RGB with its EXIF orientation applied, and its EXIF focal length in pixels (or None)."""
    try:
        with Image.open(path) as image:
            focal = exif_focal_pixels(image)  # orientation-independent: pixels are square
            oriented = ImageOps.exif_transpose(image)
            rgb = np.asarray(oriented.convert("RGB"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError, ValueError) as e:
        raise DataError(f"cannot read photo {path}: {e}") from e
    return Photo(path, np.ascontiguousarray(rgb), focal)


def common_size(sizes: Sequence[tuple[int, int]]) -> tuple[int, int]:
    """The (height, width) most photos have; ties go to the larger."""
    counts = Counter(sizes)
    return max(counts, key=lambda s: (counts[s], s[0] * s[1], s))


def fit_to_size(image: np.ndarray, height: int, width: int) -> tuple[np.ndarray, float]:
    """Centre-crops an image to the aspect ratio of (height, width), then resizes it to that size.

    Args:
        image: [h, w, 3] uint8.
        height: output height in pixels.
        width: output width in pixels.

    Returns:
        The image and the resize factor (output pixels per input pixel), which also scales a focal length in pixels
        (the crop does not change it, and keeps the principal point centred).
    """
    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image, 1.0
    if h * width > w * height:  # too tall for the target aspect: crop rows
        crop_h, crop_w = max(1, round(w * height / width)), w
    else:
        crop_h, crop_w = h, max(1, round(h * width / height))
    top, left = (h - crop_h) // 2, (w - crop_w) // 2
    cropped = image[top : top + crop_h, left : left + crop_w]
    factor = width / crop_w
    interpolation = cv2.INTER_AREA if factor < 1 else cv2.INTER_CUBIC
    return cv2.resize(cropped, (width, height), interpolation=interpolation), factor


def downscaled_size(height: int, width: int, max_size: int | None) -> tuple[int, int]:
    """(height, width) scaled down so the longer side is at most `max_size` (unchanged if None or already small).

    Args:
        height: image height in pixels.
        width: image width in pixels.
        max_size: the longest side allowed, or None.
    """
    if not max_size or max(height, width) <= max_size:
        return height, width
    scale = max_size / max(height, width)
    return max(1, round(height * scale)), max(1, round(width * scale))


# ----------------------------------------------------------------------------------------------------------------
# Cameras out


@dataclass
class Undistortion:
    """How one photo becomes a centred square-pixel pinhole image of the same size."""

    focal: float  # focal length in pixels of the output image
    maps: tuple[np.ndarray, np.ndarray] | None  # cv2.remap maps (x, y), or None: the photo is already such a camera
    max_shift: float  # largest distance in pixels between an output pixel and where it is read from


def undistortion(camera: pycolmap.Camera) -> Undistortion:
    """The undistortion of a COLMAP camera to a pinhole camera of the same size with focal s x (mean focal) and the
    principal point at the centre; s is the smallest zoom that leaves no output pixel outside the photo."""
    width, height = camera.width, camera.height
    focal = camera.mean_focal_length()

    def source(u: np.ndarray, v: np.ndarray, scale: float) -> np.ndarray:
        """COLMAP image coordinates (pixel centres at +0.5) in the photo of output coordinates u, v."""
        rays = np.stack([(u - width / 2) / (scale * focal), (v - height / 2) / (scale * focal), np.ones_like(u)], 1)
        return camera.img_from_cam(rays, check_cheirality=False)

    # Output pixel centres (COLMAP coordinates) for the maps, and the output's outline for the zoom.
    grid_v, grid_u = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    ramp_u, ramp_v = np.linspace(0, width, 4 * width + 1), np.linspace(0, height, 4 * height + 1)
    outline_u = np.concatenate([ramp_u, ramp_u, np.zeros_like(ramp_v), np.full_like(ramp_v, width)])
    outline_v = np.concatenate([np.zeros_like(ramp_u), np.full_like(ramp_u, height), ramp_v, ramp_v])

    identity = np.stack([grid_u.ravel(), grid_v.ravel()], 1)
    shift = float(np.abs(source(identity[:, 0], identity[:, 1], 1.0) - identity).max())
    if shift < _MAX_UNDISTORTION_SHIFT:
        return Undistortion(focal, None, shift)

    def inside(scale: float) -> bool:
        xy = source(outline_u, outline_v, scale)
        tolerance = 1e-6 * max(width, height)
        return bool(np.all((xy >= -tolerance) & (xy <= np.array([width, height]) + tolerance)))

    low, high = 0.25, 4.0
    if not inside(high):
        raise SfMError(f"the estimated camera ({camera.model.name}, {camera.params.tolist()}) distorts so strongly "
                        f"that no undistorted view fits in the photo; try --camera_model SIMPLE_PINHOLE. {ADVICE}")
    for _ in range(50):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if inside(middle) else (middle, high)
    xy = source(identity[:, 0], identity[:, 1], high) - 0.5  # cv2 puts pixel centres at integers
    maps = (xy[:, 0].reshape(height, width).astype(np.float32), xy[:, 1].reshape(height, width).astype(np.float32))
    return Undistortion(high * focal, maps, shift)


def undistort(image: np.ndarray, plan: Undistortion) -> np.ndarray:
    """The undistorted image.

    Args:
        image: [H, W, 3] uint8, the photo `plan` was made for.
        plan: its `undistortion`.
    """
    if plan.maps is None:
        return image
    return cv2.remap(image, plan.maps[0], plan.maps[1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


# ----------------------------------------------------------------------------------------------------------------
# The whole step


