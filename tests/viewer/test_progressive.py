import threading

import numpy as np
import pytest

from simplenerf.viewer.camera import ViewerCamera
from simplenerf.viewer.modes import Picture, RenderCancelled, RenderMode
from simplenerf.viewer.progressive import ProgressiveRenderer, RenderRequest, progressive_sides


def test_progressive_sides():
    assert progressive_sides(128) == [16, 32, 64, 128]
    assert progressive_sides(100) == [25, 50, 100]  # 100 // 8 = 12 is below 16
    assert progressive_sides(20) == [20]
    assert progressive_sides(1000, levels=2) == [500, 1000]
    with pytest.raises(ValueError):
        progressive_sides(0)


def request(side: int = 128) -> RenderRequest:
    return RenderRequest(ViewerCamera(np.eye(3, 4), 1.0, 1.0), RenderMode("rgb"), side)


def picture(side: int) -> Picture:
    return Picture(np.full((side, side, 3), side % 256, np.uint8), np.ones((side, side)))


def test_each_level_is_shown_coarse_to_fine():
    shown = []
    renderer = ProgressiveRenderer(lambda r, side, stop: picture(side), lambda p, r, final: shown.append(
        (p.rgb.shape[0], final)))
    renderer.start()
    first = request()
    renderer.submit(first)
    assert renderer.idle.wait(10)
    renderer.close()
    assert shown == [(16, False), (32, False), (64, False), (128, True)]
    assert renderer.rendered == 4 and renderer.last is first


def test_a_new_request_abandons_the_one_in_progress():
    started, release, shown = threading.Event(), threading.Event(), []

    def render(r, side, stop):
        if r.max_side == 128:  # the first request blocks at its first level until the second arrives
            started.set()
            release.wait(10)
            if stop():
                raise RenderCancelled
        return picture(side)

    renderer = ProgressiveRenderer(render, lambda p, r, final: shown.append((r.max_side, p.rgb.shape[0])))
    renderer.start()
    renderer.submit(request(128))
    assert started.wait(10)
    second = request(64)
    renderer.submit(second)
    release.set()
    assert renderer.idle.wait(10)
    renderer.close()
    assert shown == [(64, 16), (64, 32), (64, 64)]  # nothing of the abandoned request
    assert renderer.last is second


def test_a_failed_render_is_reported_and_the_next_request_served(capsys):
    def render(r, side, stop):
        if r.max_side == 32:
            raise RuntimeError("out of memory")
        return picture(side)

    shown = []
    renderer = ProgressiveRenderer(render, lambda p, r, final: shown.append((r.max_side, final)))
    renderer.start()
    renderer.submit(request(32))
    assert renderer.idle.wait(10)
    assert capsys.readouterr().err == "simplenerf viewer: render failed (RuntimeError: out of memory)\n"
    assert shown == [] and renderer.is_alive()
    renderer.submit(request(16))
    assert renderer.idle.wait(10)
    renderer.close()
    assert shown == [(16, True)]
