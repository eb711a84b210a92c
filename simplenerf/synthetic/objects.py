"""The "objects" kind of synthetic scene (the grid demo's): planes with pictures a person recognises, drawn by cv2."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from simplenerf.synthetic.scene import BACKGROUND_Z, ImageTexture, Plane, _rotation_xy

TEXEL_DENSITY = 480.0
TEXEL_BLUR = 2.0
_FONT = cv2.FONT_HERSHEY_DUPLEX


class _Canvas:
    """A picture covering [-half_s, half_s] x [-half_t, half_t] of a plane, drawn in plane units (t up)."""

    def __init__(self, half_s: float, half_t: float, distance: float, colour: Sequence[int]) -> None:
        self.half_s, self.half_t = half_s, half_t
        self.scale = TEXEL_DENSITY / distance  # texels per unit
        size = (max(2, round(2 * half_t * self.scale)), max(2, round(2 * half_s * self.scale)))
        self.image = np.empty(size + (3,), dtype=np.uint8)
        self.image[:] = colour

    def px(self, s: float, t: float) -> tuple[int, int]:
        """Pixel (column, row) of plane point (s, t)."""
        return round((s + self.half_s) * self.scale), round((self.half_t - t) * self.scale)

    def length(self, units: float) -> int:
        return max(1, round(units * self.scale))

    def gradient(self, top: Sequence[int], bottom: Sequence[int], t_top: float, t_bottom: float) -> None:
        rows = (self.half_t - (np.arange(self.image.shape[0]) + 0.5) / self.scale - t_top) / (t_bottom - t_top)
        a = np.clip(rows, 0.0, 1.0)[:, None, None]
        self.image[:] = np.round((1 - a) * np.asarray(top) + a * np.asarray(bottom)).astype(np.uint8)

    def rect(self, s0: float, t0: float, s1: float, t1: float, colour: Sequence[int], thickness: float = -1) -> None:
        width = -1 if thickness < 0 else self.length(thickness)
        cv2.rectangle(self.image, self.px(s0, t0), self.px(s1, t1), tuple(int(c) for c in colour), width)

    def circle(self, s: float, t: float, radius: float, colour: Sequence[int], thickness: float = -1) -> None:
        width = -1 if thickness < 0 else self.length(thickness)
        cv2.circle(self.image, self.px(s, t), self.length(radius), tuple(int(c) for c in colour), width, cv2.LINE_AA)

    def line(self, a: Sequence[float], b: Sequence[float], colour: Sequence[int], thickness: float) -> None:
        cv2.line(self.image, self.px(*a), self.px(*b), tuple(int(c) for c in colour), self.length(thickness),
                 cv2.LINE_AA)

    def text(self, words: str, s_centre: float, t_centre: float, height: float, colour: Sequence[int],
             weight: float = 0.15) -> None:
        """Text centred at (s, t), `height` units tall (cap height), strokes `weight` x height thick."""
        thickness = max(1, round(weight * height * self.scale))
        font_scale = height * self.scale / cv2.getTextSize("H", _FONT, 1.0, thickness)[0][1]
        (w, h), _ = cv2.getTextSize(words, _FONT, font_scale, thickness)
        col, row = self.px(s_centre, t_centre)
        cv2.putText(self.image, words, (col - w // 2, row + h // 2), _FONT, font_scale, tuple(int(c) for c in colour),
                    thickness, cv2.LINE_AA)

    def checker(self, s0: float, t0: float, s1: float, t1: float, n_s: int, n_t: int, colours) -> None:
        for i in range(n_s):
            for j in range(n_t):
                a, b = s0 + (s1 - s0) * i / n_s, t0 + (t1 - t0) * j / n_t
                c, d = s0 + (s1 - s0) * (i + 1) / n_s, t0 + (t1 - t0) * (j + 1) / n_t
                self.rect(a, b, c, d, colours[(i + j) % 2])

    def stripes(self, period: float, angle_degrees: float, colours) -> None:
        """Stripes over the whole picture, `period` units, at an angle to the s axis."""
        rows, cols = np.indices(self.image.shape[:2], dtype=np.float64)
        s, t = cols / self.scale - self.half_s, self.half_t - rows / self.scale
        a = math.radians(angle_degrees)
        phase = np.floor((s * math.cos(a) + t * math.sin(a)) / (period / 2)).astype(np.int64) % 2
        self.image[:] = np.asarray(colours, dtype=np.uint8)[phase]

    def texture(self, name: str) -> ImageTexture:
        image = cv2.GaussianBlur(self.image.astype(np.float32) / 255.0, (0, 0), TEXEL_BLUR)
        return ImageTexture(name, image, (-self.half_s, self.half_s, -self.half_t, self.half_t))


def _dice_face(pips: int, half: float, distance: float, pip_colour: Sequence[int] = (20, 20, 20)) -> _Canvas:
    canvas = _Canvas(half, half, distance, (236, 232, 220))
    canvas.rect(-half, -half, half, half, (60, 60, 60), thickness=0.06)
    q = 0.5 * half
    spots = {1: [(0, 0)], 3: [(-q, q), (0, 0), (q, -q)], 5: [(-q, q), (q, q), (0, 0), (-q, -q), (q, -q)],
             6: [(-q, q), (q, q), (-q, 0), (q, 0), (-q, -q), (q, -q)]}[pips]
    for s, t in spots:
        canvas.circle(s, t, 0.17 * half * (1.6 if pips == 1 else 1.0), pip_colour)
    return canvas


def _plane(name: str, centre: Sequence[float], rotation: np.ndarray, half: tuple[float, float],
           texture: ImageTexture, round_: bool = False) -> Plane:
    return Plane(name, np.asarray(centre, dtype=np.float64), rotation[:, 0].copy(), rotation[:, 1].copy(),
                 half, texture, round_)


def _objects() -> tuple[Plane, ...]:
    """The "objects" scene: a wall with a poster, text and a clock; a checkered floor; a dice; a calibration board;
    a dartboard; a hazard-striped sign and a slanted poster, at depths 3.6 to 10 (fixed layout, no randomness)."""
    fronto = np.eye(3)
    floor_rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # s = x, t = -z, normal +y
    side_rot = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # s = +z, t = y, normal -x
    floor_y, wall_z = -2.2, BACKGROUND_Z

    wall = _Canvas(7.5, 5.5, -wall_z, (0, 0, 0))
    wall.stripes(0.5, 90.0, [(150, 105, 70), (178, 130, 88)])  # wooden panelling below the dado rail...
    painted = _Canvas(7.5, 5.5, -wall_z, (0, 0, 0))
    painted.gradient((150, 190, 232), (232, 212, 176), 5.5, floor_y)
    rail = wall.px(0.0, -1.2)[1]
    wall.image[:rail] = painted.image[:rail]  # ...and a painted wall above it
    wall.rect(-7.5, -1.2, 7.5, -1.05, (110, 70, 40))
    wall.rect(-4.7, 0.5, -1.3, 3.1, (245, 245, 245))  # the poster: white frame, navy, yellow title, mountains
    wall.rect(-4.5, 0.7, -1.5, 2.9, (30, 40, 90))
    wall.text("NeRF", -3.0, 2.25, 0.8, (250, 210, 40), weight=0.18)
    mountains = np.array([wall.px(-4.5, 0.7), wall.px(-3.8, 1.5), wall.px(-3.2, 1.0), wall.px(-2.4, 1.7),
                          wall.px(-1.5, 0.9), wall.px(-1.5, 0.7)], dtype=np.int32)
    cv2.fillPoly(wall.image, [mountains], (90, 160, 90), cv2.LINE_AA)
    wall.text("SimpleNeRF", -3.0, -0.2, 0.42, (40, 40, 40))
    wall.circle(3.2, 2.0, 1.0, (250, 250, 250))  # a clock at ten past ten
    wall.circle(3.2, 2.0, 1.0, (30, 30, 30), thickness=0.1)
    for hour in range(12):
        a = math.radians(30 * hour)
        wall.line((3.2 + 0.75 * math.sin(a), 2.0 + 0.75 * math.cos(a)),
                  (3.2 + 0.9 * math.sin(a), 2.0 + 0.9 * math.cos(a)), (30, 30, 30), 0.06)
    wall.line((3.2, 2.0), (3.2 - 0.45 * math.sin(math.radians(60)), 2.0 + 0.45 * math.cos(math.radians(60))),
              (30, 30, 30), 0.09)
    wall.line((3.2, 2.0), (3.2 + 0.7 * math.sin(math.radians(60)), 2.0 + 0.7 * math.cos(math.radians(60))),
              (30, 30, 30), 0.06)
    wall.text("12", 3.2, 2.55, 0.2, (30, 30, 30))

    floor = _Canvas(7.5, 3.4, 7.0, (0, 0, 0))
    floor.checker(-7.5, -3.4, 7.5, 3.4, 18, 8, [(196, 150, 98), (116, 78, 50)])

    board = _Canvas(0.6, 0.45, 3.6, (250, 250, 250))  # a calibration checkerboard, 8 x 6 with a white margin
    board.checker(-0.52, -0.37, 0.52, 0.37, 8, 6, [(20, 20, 20), (250, 250, 250)])

    dart = _Canvas(0.55, 0.55, 5.0, (40, 40, 40))
    for ring, colour in enumerate([(200, 30, 30), (245, 240, 225), (200, 30, 30), (245, 240, 225), (30, 130, 60)]):
        dart.circle(0.0, 0.0, 0.55 * (1.0 - ring / 5.5), colour)

    sign = _Canvas(0.5, 1.8, 8.5, (0, 0, 0))
    sign.stripes(0.5, 45.0, [(245, 200, 20), (25, 25, 25)])
    sign.rect(-0.5, 0.6, 0.5, 1.8, (240, 240, 240))
    sign.text("STOP", 0.0, 1.2, 0.28, (200, 30, 30), weight=0.2)

    poster = _Canvas(1.0, 1.5, 7.8, (0, 0, 0))
    poster.gradient((120, 60, 160), (250, 150, 60), 1.5, -1.5)
    poster.text("3D", 0.0, 0.7, 0.8, (255, 255, 255), weight=0.2)
    for k, colour in enumerate([(230, 60, 60), (240, 200, 40), (60, 170, 80), (50, 110, 220)]):
        poster.rect(-0.8, -0.3 - 0.3 * k, 0.8, -0.45 - 0.3 * k, colour)

    return (
        _plane("wall", (0.0, 0.0, wall_z), fronto, (math.inf, math.inf), wall.texture("wall")),
        _plane("floor", (0.0, floor_y, -6.6), floor_rot, (7.5, 3.4), floor.texture("floor")),
        _plane("dice_front", (1.5, -1.6, -5.8), fronto, (0.6, 0.6), _dice_face(5, 0.6, 5.8).texture("dice_5")),
        _plane("dice_side", (0.9, -1.6, -6.4), side_rot, (0.6, 0.6), _dice_face(3, 0.6, 6.4).texture("dice_3")),
        _plane("dice_top", (1.5, -1.0, -6.4), floor_rot, (0.6, 0.6),
               _dice_face(1, 0.6, 6.4, (200, 30, 30)).texture("dice_1")),
        _plane("board", (-1.5, -0.7, -3.6), _rotation_xy(math.radians(25.0), 0.0), (0.6, 0.45),
               board.texture("checkerboard")),
        _plane("dartboard", (-0.1, 1.0, -5.0), fronto, (0.55, 0.55), dart.texture("dartboard"), round_=True),
        _plane("sign", (1.2, -0.2, -8.5), fronto, (0.5, 1.8), sign.texture("hazard_sign")),
        _plane("poster", (3.3, 0.3, -7.8), _rotation_xy(math.radians(-40.0), 0.0), (1.0, 1.5),
               poster.texture("poster")),
    )


