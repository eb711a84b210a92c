"""Progressive rendering: a coarse render first, then finer ones while the camera rests.

Each browser (client) has a `ProgressiveRenderer` thread. Every camera move, menu change or (while training) new
weights submits a `RenderRequest`; the thread renders it at the sides of `progressive_sides` (1/8, 1/4, 1/2 and all of
the chosen resolution) and shows each picture as it is done. A newer request abandons the current one between two
chunks of rays (`modes.RenderCancelled`), so while the camera moves only the cheap first levels are drawn, and the
last, full-resolution one arrives once it rests. A failed render is reported on one line and the thread goes on.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass

from simplenerf.viewer.camera import ViewerCamera
from simplenerf.viewer.modes import Picture, RenderCancelled, RenderMode


def progressive_sides(max_side: int, levels: int = 4, min_side: int = 16) -> list[int]:
    """The larger side (pixels) of each successive render: max_side / 2^(levels - 1), ..., max_side / 2, max_side,
    without those below `min_side` (max_side itself always comes last)."""
    if max_side < 1 or levels < 1:
        raise ValueError(f"max_side and levels must be positive, got {max_side}, {levels}")
    sides = [max_side // 2**k for k in range(levels - 1, 0, -1) if max_side // 2**k >= min_side]
    return [*sides, max_side]


@dataclass(frozen=True, eq=False)
class RenderRequest:
    """What a client asked for: its camera, the render mode, the resolution (larger side) and the weights' version."""

    camera: ViewerCamera
    mode: RenderMode
    max_side: int
    version: int = 0


RenderFn = Callable[[RenderRequest, int, Callable[[], bool]], Picture]  # (request, side, stop) -> picture
ShowFn = Callable[[Picture, RenderRequest, bool], None]  # (picture, request, final)


class ProgressiveRenderer(threading.Thread):
    """Renders one client's latest request, level by level (a daemon thread; `close` ends it)."""

    def __init__(self, render: RenderFn, show: ShowFn, levels: int = 4, name: str = "viewer-render") -> None:
        super().__init__(daemon=True, name=name)
        self._render, self._show, self.levels = render, show, levels
        self._pending: RenderRequest | None = None
        self._wake = threading.Event()
        self._closed = False
        self.idle = threading.Event()  # set while nothing is left to render (tests wait on it)
        self.idle.set()
        self.rendered = 0  # pictures shown so far
        self.last: RenderRequest | None = None  # the request whose full-resolution picture was shown last

    def submit(self, request: RenderRequest) -> None:
        """Renders `request` next, abandoning the one in progress."""
        self.idle.clear()
        self._pending = request
        self._wake.set()

    @property
    def pending(self) -> RenderRequest | None:
        return self._pending

    def close(self) -> None:
        self._closed = True
        self._wake.set()

    def run(self) -> None:
        while not self._closed:
            if not self._wake.wait(0.5):
                continue
            self._wake.clear()
            request = self._pending
            if request is None or self._closed:
                continue
            self._render_levels(request)
            if self._pending is request:
                self.idle.set()

    def _render_levels(self, request: RenderRequest) -> None:
        def stop() -> bool:
            return self._closed or self._pending is not request

        sides = progressive_sides(request.max_side, self.levels)
        for side in sides:
            try:
                picture = self._render(request, side, stop)
            except RenderCancelled:
                return
            except Exception as e:  # a render must not end the viewer (nor a training run): say it, wait for the next
                print(f"simplenerf viewer: render failed ({type(e).__name__}: {e})", file=sys.stderr, flush=True)
                return
            if stop():
                return
            final = side == sides[-1]
            self._show(picture, request, final)
            self.rendered += 1
            if final:
                self.last = request
