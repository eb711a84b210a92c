"""The synthetic scene's description: textures, planes, cameras and the "planes" kind of scene (see
`simplenerf.synthetic.generate` for the whole convention); the "objects" kind is `simplenerf.synthetic.objects`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# Bump whenever the generated content changes, so that cached scenes on disk are rebuilt instead of reused.
FORMAT_VERSION = 1
HFOV_DEGREES = 55.0
BACKGROUND_Z = -10.0
SCENE_CENTRE = (0.0, 0.0, -6.0)
NUM_SINUSOIDS = 16


@dataclass(frozen=True)
class Texture:
    """Procedural colour in a plane's 2D coordinates (s, t), in world units.

    colour(s, t) = 0.5 + 0.5 * tanh(bias + sum_k amps[k] * colours[k] * sin(2 pi freqs[k] . (s, t) + phases[k])
                                    + checker_strength * soft_checker(s, t))
    """

    bias: np.ndarray  # [3], pre-tanh base colour
    freqs: np.ndarray  # [K, 2], cycles per world unit
    phases: np.ndarray  # [K]
    amps: np.ndarray  # [K]
    colours: np.ndarray  # [K, 3], unit-norm colour directions
    checker_period: float
    checker_strength: float

    def __call__(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Colour [..., 3] float32 in (0, 1) at plane coordinates s, t [...]."""
        return self.channels_first(s, t).T.reshape(np.shape(s) + (3,))

    def channels_first(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Colour [3, P] float32 of the flattened s, t: channel planes are what image assembly copies fastest."""
        # float32 throughout: the transcendentals are ~10x faster than in float64 and phases of at most ~100 rad
        # lose ~1e-5, far below the 8-bit output. [K, P] layouts keep every product a contiguous vectorised op.
        s32 = np.asarray(s, dtype=np.float32).reshape(1, -1)
        t32 = np.asarray(t, dtype=np.float32).reshape(1, -1)
        f32 = (2.0 * np.pi * self.freqs).astype(np.float32)
        phase = f32[:, 0:1] * s32 + f32[:, 1:2] * t32 + self.phases.astype(np.float32)[:, None]
        weights = (self.colours.T * self.amps).astype(np.float32)  # [3, K]
        logits = weights @ np.sin(phase) + self.bias.astype(np.float32)[:, None]  # [3, P]
        # tanh of a product of sines keeps the checker smooth (band-limited up to a few harmonics) but corner-rich.
        w = np.float32(2.0 * np.pi / self.checker_period)
        checker = np.tanh(np.float32(2.0) * np.sin(w * s32) * np.sin(w * t32))
        logits += np.float32(self.checker_strength / math.tanh(2.0)) * checker
        return np.float32(0.5) + np.float32(0.5) * np.tanh(logits)

    def describe(self) -> dict[str, object]:
        """JSON-friendly summary (for scene.json)."""
        return {
            "texture_wavelengths": (1.0 / np.linalg.norm(self.freqs, axis=1)).tolist(),
            "checker_period": self.checker_period,
        }


@dataclass(frozen=True, eq=False)
class ImageTexture:
    """A procedural picture (drawn with cv2: checkerboards, stripes, text, gradients, shapes) stretched over the
    rectangle [s_min, s_max] x [t_min, t_max] of a plane's coordinates, sampled bilinearly and clamped at its edges.

    Row 0 of the picture is at t_max (t points up in the picture), column 0 at s_min.
    """

    name: str
    image: np.ndarray  # [h, w, 3] float32 in [0, 1]
    extent: tuple[float, float, float, float]  # s_min, s_max, t_min, t_max

    def __call__(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Colour [..., 3] float32 in [0, 1] at plane coordinates s, t [...]."""
        return self.channels_first(s, t).T.reshape(np.shape(s) + (3,))

    def channels_first(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Colour [3, P] float32 of the flattened s, t."""
        h, w = self.image.shape[:2]
        s_min, s_max, t_min, t_max = self.extent
        col = np.clip((np.ravel(s) - s_min) / (s_max - s_min) * (w - 1), 0.0, w - 1.0)
        row = np.clip((t_max - np.ravel(t)) / (t_max - t_min) * (h - 1), 0.0, h - 1.0)
        c0 = np.minimum(np.floor(col).astype(np.int64), w - 2)
        r0 = np.minimum(np.floor(row).astype(np.int64), h - 2)
        fc = (col - c0).astype(np.float32)[:, None]
        fr = (row - r0).astype(np.float32)[:, None]
        img = self.image
        top = img[r0, c0] * (1 - fc) + img[r0, c0 + 1] * fc
        bottom = img[r0 + 1, c0] * (1 - fc) + img[r0 + 1, c0 + 1] * fc
        return np.ascontiguousarray((top * (1 - fr) + bottom * fr).T, dtype=np.float32)

    def describe(self) -> dict[str, object]:
        """JSON-friendly summary (for scene.json)."""
        return {"texture": self.name, "texture_extent": list(self.extent), "texture_size": list(self.image.shape[:2])}


@dataclass(frozen=True)
class Plane:
    """A textured planar patch: points centre + s * axis_s + t * axis_t with |s| <= half_extent[0], |t| <= ...[1]
    (or, if `round`, inside the ellipse with those half axes).

    The background uses an infinite half extent. `normal` = axis_s x axis_t points towards the cameras (+z).
    """

    name: str
    centre: np.ndarray  # [3]
    axis_s: np.ndarray  # [3], unit
    axis_t: np.ndarray  # [3], unit, orthogonal to axis_s
    half_extent: tuple[float, float]
    texture: Texture | ImageTexture
    round: bool = False

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_s, self.axis_t)

    @property
    def bounded(self) -> bool:
        return bool(np.isfinite(self.half_extent[0]) and np.isfinite(self.half_extent[1]))

    def describe(self) -> dict[str, object]:
        """JSON-friendly summary (for scene.json)."""
        return {
            "name": self.name,
            "centre": self.centre.tolist(),
            "axis_s": self.axis_s.tolist(),
            "axis_t": self.axis_t.tolist(),
            "normal": self.normal.tolist(),
            "half_extent": list(self.half_extent) if self.bounded else None,
            **({"round": True} if self.round else {}),
            **self.texture.describe(),
        }


@dataclass(frozen=True)
class SyntheticScene:
    """Planes, cameras and full-resolution intrinsics of one synthetic scene.

    planes[0] is always the infinite background. c2w is [N, 3, 4] in OpenGL axes (columns right, up, back, centre).
    `focal` belongs to the full resolution (height, width); at factor k use focal / k and the centre of the smaller
    image (`intrinsics`).
    """

    seed: int
    height: int
    width: int
    focal: float
    planes: tuple[Plane, ...]
    c2w: np.ndarray  # [N, 3, 4] float64
    kind: str = "planes"

    @property
    def n_frames(self) -> int:
        return int(self.c2w.shape[0])

    def intrinsics(self, factor: int = 1) -> tuple[int, int, float]:
        """(height, width, focal) of the images at `factor`; the principal point is (width / 2, height / 2)."""
        _check_factor(self.height, self.width, factor)
        return self.height // factor, self.width // factor, self.focal / factor


def _check_factor(height: int, width: int, factor: int) -> None:
    if not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factors must be positive integers, got {factor!r}")
    if height % factor or width % factor:
        raise ValueError(
            f"full resolution {height}x{width} (HxW) is not divisible by factor {factor}; "
            f"choose height and width that are multiples of every requested factor"
        )


def _rotation_xy(yaw: float, pitch: float) -> np.ndarray:
    """R = R_y(yaw) @ R_x(pitch)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    r_y = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return r_y @ r_x


def _random_texture(rng: np.random.Generator, distance: float) -> Texture:
    # Wavelengths scale with the viewing distance so every plane has the same on-screen band: ~5-31 px at the default
    # 128-px width (still above the 2-px Nyquist limit at 64 px) and ~19-121 px at 504 px, where SIFT finds ~700
    # keypoints per view. Many random orientations avoid stripe-like, repetitive (ambiguous to match) patterns.
    wavelengths = distance * np.exp(rng.uniform(math.log(0.04), math.log(0.25), NUM_SINUSOIDS))
    angles = rng.uniform(0.0, np.pi, NUM_SINUSOIDS)
    freqs = np.stack([np.cos(angles), np.sin(angles)], axis=1) / wavelengths[:, None]
    colours = rng.normal(size=(NUM_SINUSOIDS, 3))
    colours /= np.linalg.norm(colours, axis=1, keepdims=True)
    return Texture(
        bias=rng.uniform(-1.0, 1.0, 3),
        freqs=freqs,
        phases=rng.uniform(0.0, 2.0 * np.pi, NUM_SINUSOIDS),
        amps=rng.uniform(0.3, 0.6, NUM_SINUSOIDS),
        colours=colours,
        checker_period=float(distance * rng.uniform(0.15, 0.25)),
        checker_strength=float(rng.uniform(0.3, 0.5)),
    )


def _fronto(
    rng: np.random.Generator, name: str, centre: Sequence[float], half: Sequence[float], jitter: float
) -> Plane:
    centre_arr = np.asarray(centre, dtype=np.float64) + rng.uniform(-jitter, jitter, 3)
    half_extent = (float(half[0] * rng.uniform(0.9, 1.1)), float(half[1] * rng.uniform(0.9, 1.1)))
    return Plane(
        name=name,
        centre=centre_arr,
        axis_s=np.array([1.0, 0.0, 0.0]),
        axis_t=np.array([0.0, 1.0, 0.0]),
        half_extent=half_extent,
        texture=_random_texture(rng, -float(centre_arr[2])),
    )


def _camera_centres(rng: np.random.Generator, n_frames: int) -> np.ndarray:
    cols = max(1, round(math.sqrt(n_frames * 1.5)))
    rows = math.ceil(n_frames / cols)
    xs = np.linspace(-0.3, 0.3, cols) if cols > 1 else np.zeros(1)
    ys = np.linspace(0.2, -0.2, rows) if rows > 1 else np.zeros(1)
    grid = np.array([(x, y, 0.0) for y in ys for x in xs])[:n_frames]
    jitter = rng.uniform(-1.0, 1.0, (n_frames, 3)) * np.array([0.03, 0.03, 0.05])
    return grid + jitter


def _sweep_centres(rng: np.random.Generator, n_frames: int) -> np.ndarray:
    """Camera centres of a handheld left-to-right sweep (frame order = capture order): x from -0.3 to 0.3 (the
    "planes" grid's baseline), a gentle vertical wave of +-0.06 and jitter, so the every-8th test frames sit between
    or just beyond train frames."""
    i = np.arange(n_frames)
    x = np.linspace(-0.3, 0.3, n_frames) if n_frames > 1 else np.zeros(1)
    y = 0.06 * np.sin(3.0 * np.pi * i / max(n_frames - 1, 1))
    jitter = rng.uniform(-1.0, 1.0, (n_frames, 3)) * np.array([0.015, 0.015, 0.05])
    return np.stack([x, y, np.zeros(n_frames)], axis=1) + jitter


def _look_at(centre: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    back = centre - target
    back /= np.linalg.norm(back)
    right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    # Roll about the viewing axis so that the rotations are not all yaw/pitch-only.
    c, s = math.cos(roll), math.sin(roll)
    right, up = c * right + s * up, -s * right + c * up
    return np.concatenate([np.stack([right, up, back], axis=1), centre[:, None]], axis=1)


SCENE_KINDS = ("planes", "objects")


def _noise_planes(rng: np.random.Generator) -> tuple[Plane, ...]:
    """The "planes" scene: band-limited colour-noise textures on a background and four rectangles."""
    background = Plane(
        name="background",
        centre=np.array([0.0, 0.0, BACKGROUND_Z]),
        axis_s=np.array([1.0, 0.0, 0.0]),
        axis_t=np.array([0.0, 1.0, 0.0]),
        half_extent=(math.inf, math.inf),
        texture=_random_texture(rng, -BACKGROUND_Z),
    )
    # The layout skeleton is fixed (only jittered) so that occlusions between the planes exist for every seed.
    far = _fronto(rng, "far_rect", (-1.2, 0.6, -7.0), (1.6, 1.2), 0.25)
    mid = _fronto(rng, "mid_rect", (1.0, -0.3, -5.0), (1.0, 1.0), 0.25)
    near = _fronto(rng, "near_rect", (-0.3, -0.5, -3.2), (0.5, 0.4), 0.15)
    slant_centre = np.array([1.6, 1.3, -6.0]) + rng.uniform(-0.15, 0.15, 3)
    slant_rot = _rotation_xy(math.radians(rng.uniform(30.0, 40.0)), math.radians(rng.uniform(-15.0, -5.0)))
    slanted = Plane(
        name="slanted_rect",
        centre=slant_centre,
        axis_s=slant_rot[:, 0],
        axis_t=slant_rot[:, 1],
        half_extent=(float(rng.uniform(0.75, 0.85)), float(rng.uniform(0.55, 0.65))),
        texture=_random_texture(rng, -float(slant_centre[2])),
    )
    return background, far, mid, near, slanted


# The "objects" scene's pictures: texels per world unit are TEXEL_DENSITY / distance, about 4 texels per pixel at
# the default 128-px width (focal ~123 px), and each picture is blurred by TEXEL_BLUR texels (~0.5 px there) so that
# the point-sampled images alias little at small sizes; at larger sizes the pictures look soft.
