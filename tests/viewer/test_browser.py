"""The viewer in a real browser: Debian's Chromium, headless, driven by Playwright (which never downloads a browser
here: it is given the system's). Skipped where either is missing."""

from __future__ import annotations

import shutil
import time

import cv2
import numpy as np
import pytest

from simplenerf.viewer.modes import RenderMode

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs the system's Chromium (Debian: apt-get install "
                                "chromium); the test does not download a browser")


def wait_for(condition, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.1)


def canvas(page) -> np.ndarray:
    """The page's left half (the 3D canvas, away from the control panel) as BGR pixels."""
    picture = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_COLOR)
    return picture[:, : picture.shape[1] // 2]


def test_a_browser_gets_renders_that_follow_its_camera_and_the_mask_view(viewer):
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the dev extra)")
    viewer.resolution.value = 64
    viewer.set_mode(RenderMode("rgb"))
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
        try:
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(viewer.url)
            wait_for(lambda: any(r.last is not None for r in viewer.renderers.values()), 20, "a first render")
            (renderer,) = viewer.renderers.values()
            first = renderer.last
            assert first.mode == RenderMode("rgb") and first.max_side == 64
            page.wait_for_timeout(500)  # the picture travels to the page
            seen = canvas(page)
            assert seen.std() > 10, "the page shows a blank canvas"

            page.mouse.move(200, 300)  # drag: the browser's camera orbits, a new render follows it
            page.mouse.down()
            page.mouse.move(260, 330, steps=5)
            page.mouse.up()
            wait_for(lambda: renderer.last is not first, 20, "a render of the moved camera")
            assert not np.allclose(renderer.last.camera.c2w, first.camera.c2w)

            viewer.set_mode(RenderMode("mask", "points"))  # what the menu does when "mask: points" is picked
            wait_for(lambda: renderer.last.mode.kind == "mask", 20, "the mask view")
            page.wait_for_timeout(500)
            masked = canvas(page)
            assert masked.std() > 10 and np.abs(masked.astype(int) - seen.astype(int)).mean() > 5

            viewer.refresh_seconds = 0.0  # training: new weights re-render the browser's view, with the step
            viewer.weights_changed(7)
            wait_for(lambda: renderer.last.version == viewer.version, 20, "a render of the new weights")
            assert viewer.status.content.startswith("step 7 · mask: points")
        finally:
            browser.close()
