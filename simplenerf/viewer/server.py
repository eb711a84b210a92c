"""The viewer: a viser server showing a SimpleNeRF model, its cameras and SfM points, and renders from each browser's
camera (`simplenerf view RUN`, or during `fit --viewer true`).

One `Viewer` serves any number of browsers; each gets a `ProgressiveRenderer` thread fed by its camera. The menu
("render": `modes.render_modes`), the resolution, the camera-path keyframes and the screenshot button are shared by
all browsers. While training, `weights_changed` (called after every step; nothing but a counter when nobody is
connected) re-renders the browsers' views from the latest weights at most every `refresh_seconds`.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np
import torch

from simplenerf.errors import SimpleNeRFError

try:
    import viser
except ModuleNotFoundError:  # an install without the extra: one line, not a traceback
    raise SimpleNeRFError("the viewer needs viser: pip install -e '.[viewer]' (viser==1.1.1)") from None

from simplenerf.data.datasets import SparseDepthPool
from simplenerf.data.scene import Scene
from simplenerf.method.module import SimpleNeRF
from simplenerf.viewer.camera import (
    ViewerCamera,
    camera_from_viser,
    look_at_point,
    nearest_camera,
    vertical_fov,
    viewer_rays,
    viser_pose,
)
from simplenerf.viewer.export import camera_path, save_camera_path, save_screenshot
from simplenerf.viewer.modes import Picture, RenderMode, render_modes, render_picture
from simplenerf.viewer.progressive import ProgressiveRenderer, RenderRequest
from simplenerf.viewer.scene import TEST_COLOUR, TRAIN_COLOUR, add_cameras, add_points, frustum_scale, sfm_points

FAR_DEPTH = 1000.0  # depth given to the browser where nothing was rendered: everything of the 3D scene shows there
LEGEND = ("**mask** (nearest train view): <span style='color:#1ad933'>green</span> +1, the augmented (or fine) "
          "depth supervises the main one; <span style='color:#e61acc'>magenta</span> -1, the main depth supervises "
          "it; grey 0, neither; dim: not seen by that view.")


class PortInUse(SimpleNeRFError):
    """The viewer's port is taken, is no port number, or its host is not this machine's."""


def check_port(host: str, port: int) -> None:
    """PortInUse unless a server can listen on host:port (port 0: any free port, always fine). viser would quietly
    move to the next free port, and the printed URL would then not be the one asked for."""
    if not 0 <= port <= 65535:
        raise PortInUse(f"port {port} is not a port number: expected 0-65535 (0: any free one)")
    if port == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server will: only a listener blocks
        try:
            probe.bind((host, port))
        except socket.gaierror as e:
            raise PortInUse(f"cannot listen on host {host}: {e.strerror}; give an address of this machine with "
                            "--host (127.0.0.1, 0.0.0.0: every interface)") from None
        except OSError as e:
            raise PortInUse(f"port {port} on {host} is in use ({e.strerror}): choose another with --port N, or "
                            f"--port 0 for any free one") from None


def depth_range_of(scene: Scene) -> tuple[float, float]:
    """(closest, farthest) depth of the colour maps: 0.9 x the nearest and the farthest bound of the scene's frames."""
    return 0.9 * float(np.min(scene.bounds[:, 0])), float(np.max(scene.bounds[:, 1]))


class Viewer:
    """A running viewer of `model` (a `SimpleNeRF`) on the frames of `scene`."""

    def __init__(
        self,
        model: SimpleNeRF,
        scene: Scene,
        near: float,
        out_dir: Path,
        sparse: SparseDepthPool | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        max_side: int | None = None,
        refresh_seconds: float = 2.0,
    ) -> None:
        check_port(host, port)
        self.model, self.scene, self.near, self.out_dir = model, scene, near, Path(out_dir)
        self.train = scene.views.subset(scene.split.train)
        self.depth_range = depth_range_of(scene)
        self.modes = render_modes(model)
        self.refresh_seconds = refresh_seconds
        self.version, self.step = 0, None  # weights' version (training: steps), shown step
        self._last_refresh = 0.0
        self._masks: dict[int, tuple[int, dict[str, torch.Tensor]]] = {}  # train view -> (version, maps)
        self._masks_lock = threading.Lock()
        self.renderers: dict[int, ProgressiveRenderer] = {}
        self.keyframes: list[ViewerCamera] = []
        self.server = viser.ViserServer(host=host, port=port, label="simplenerf", verbose=False)
        if port and self.server.get_port() != port:  # taken between the check and the server's start
            self.server.stop()
            raise PortInUse(f"port {port} on {host} is in use: choose another with --port N, or --port 0")
        self.url = f"http://{host}:{self.server.get_port()}"
        self._set_scene(sparse)
        self._build_gui(max_side or max(self.train.width, self.train.height))
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)

    # ----- scene and menu -----
    def _set_scene(self, sparse: SparseDepthPool | None) -> None:
        server, scene = self.server, self.scene
        server.scene.set_up_direction("+y")  # OpenGL world axes, as the data's (LLFF scenes are recentred so)
        scale = frustum_scale(scene.bounds)
        add_cameras(server, scene.views, scene.split.train, "train", TRAIN_COLOUR, scale)
        add_cameras(server, scene.views, scene.split.test, "test", TEST_COLOUR, scale)
        if sparse is not None and len(sparse):
            add_points(server, sfm_points(sparse, self.train), size=0.2 * scale)
        # The first view: the train cameras' mean pose, moved back so that their frustums are in sight.
        mean = self.train.c2w.detach().cpu().double().mean(0).numpy()
        axes, upper = np.linalg.qr(mean[:, :3])  # the nearest rotation's columns, up to sign
        axes *= np.sign(np.diag(upper))
        start = np.concatenate([axes, (mean[:, 3] + 10 * scale * axes[:, 2])[:, None]], axis=1)
        server.initial_camera.position = start[:, 3]
        server.initial_camera.look_at = look_at_point(start, float(np.median(scene.bounds[:, 0])))
        server.initial_camera.up = start[:, 1]
        server.initial_camera.fov = vertical_fov(self.train.intrinsics[0], self.train.height)

    def _build_gui(self, max_side: int) -> None:
        gui = self.server.gui
        self.status = gui.add_markdown("connecting ...")
        labels = tuple(m.label for m in self.modes)
        self.mode_menu = gui.add_dropdown("Render", labels, initial_value=labels[0])
        self.resolution = gui.add_slider("Resolution", min=32, max=2048, step=16, initial_value=max_side,
                                         hint="larger side of the finest render (pixels)")
        self.show_scene = gui.add_checkbox("Cameras and points", initial_value=True)
        self.mode_menu.on_update(lambda _: self.rerender())
        self.resolution.on_update(lambda _: self.rerender())
        self.show_scene.on_update(lambda _: self.server.scene.set_global_visibility(self.show_scene.value))
        gui.add_markdown(LEGEND)
        self.screenshot_button = gui.add_button("Screenshot", hint="save the current render as a PNG")
        self.screenshot_button.on_click(lambda event: self.screenshot(event.client))
        with gui.add_folder("Camera path"):
            self.frames_per_segment = gui.add_number("Frames per segment", initial_value=30, min=1, step=1)
            self.fps = gui.add_number("fps", initial_value=30.0, min=1.0)
            add = gui.add_button("Add keyframe", hint="the current camera")
            clear = gui.add_button("Clear keyframes")
            export = gui.add_button("Export camera path", hint="a file `simplenerf render-video --trajectory` takes")
        add.on_click(lambda event: self.add_keyframe(event.client))
        clear.on_click(lambda _: self.clear_keyframes())
        export.on_click(lambda event: self.export_path(event.client))

    @property
    def mode(self) -> RenderMode:
        return next(m for m in self.modes if m.label == self.mode_menu.value)

    def set_mode(self, mode: RenderMode) -> None:
        """Selects `mode` in the menu (for every browser) and re-renders."""
        self.mode_menu.value = mode.label
        self.rerender()

    # ----- browsers -----
    def _connect(self, client: viser.ClientHandle) -> None:
        renderer = ProgressiveRenderer(self.render, lambda p, r, f: self._show(client, p, r, f),
                                       name=f"viewer-render-{client.client_id}")
        self.renderers[client.client_id] = renderer
        renderer.start()
        client.camera.on_update(lambda _: renderer.submit(self.request(client)))
        renderer.submit(self.request(client))

    def _disconnect(self, client: viser.ClientHandle) -> None:
        renderer = self.renderers.pop(client.client_id, None)
        if renderer is not None:
            renderer.close()

    def camera_of(self, client: viser.ClientHandle) -> ViewerCamera:
        camera = client.camera
        return camera_from_viser(camera.wxyz, camera.position, camera.fov, camera.aspect)

    def request(self, client: viser.ClientHandle) -> RenderRequest:
        return RenderRequest(self.camera_of(client), self.mode, int(self.resolution.value), self.version)

    def rerender(self) -> None:
        """Renders every browser's view afresh (a new mode, resolution or weights)."""
        for client_id, renderer in list(self.renderers.items()):
            client = self.server.get_clients().get(client_id)
            if client is not None:
                renderer.submit(self.request(client))

    def weights_changed(self, step: int) -> None:
        """Training: the weights of step `step` are in the model. Re-renders at most every `refresh_seconds`, and
        only for connected browsers (otherwise this is two assignments)."""
        self.version, self.step = self.version + 1, step
        if self.renderers and time.monotonic() - self._last_refresh >= self.refresh_seconds:
            self._last_refresh = time.monotonic()
            self.rerender()

    # ----- rendering -----
    def masks_of(self, view: int) -> dict[str, torch.Tensor]:
        """The reliability masks [h, w] of train view `view` by pair name (`SimpleNeRF.reliability_maps`), computed
        once per view and weights' version."""
        with self._masks_lock:
            cached = self._masks.get(view)
            if cached is None or cached[0] != self.version:
                self._masks[view] = cached = (self.version, self.model.reliability_maps(view))
            return cached[1]

    def render(self, request: RenderRequest, side: int, stop=lambda: False) -> Picture:
        """The picture of `request` at larger side `side` (a `ProgressiveRenderer`'s render function)."""
        camera, mode = request.camera, request.mode
        width, height = camera.image_size(side)
        like = next(self.model.parameters())
        ndc = (self.train.intrinsics[0], self.train.width, self.train.height)
        rays, valid = viewer_rays(camera, width, height, self.near, ndc, like)
        mask = None
        nearest = nearest_camera(camera, self.train.c2w)
        if mode.kind == "mask":
            mask = (self.masks_of(nearest)[mode.name], self.model.train_views, nearest)
        start = time.perf_counter()
        picture = render_picture(self.model, rays, valid, width, height, mode, self.depth_range, mask, stop)
        step = "" if self.step is None else f"step {self.step} · "
        self.status.content = (f"{step}{mode.label} {width}x{height} in {1e3 * (time.perf_counter() - start):.0f} "
                               f"ms · nearest train view {nearest} ({self.train.names[nearest]})")
        return picture

    def _show(self, client: viser.ClientHandle, picture: Picture, request: RenderRequest, final: bool) -> None:
        depth = np.where(picture.depth > 0, picture.depth, FAR_DEPTH)
        client.scene.set_background_image(picture.rgb, format="png" if final else "jpeg", jpeg_quality=85,
                                          depth=depth)

    # ----- exports -----
    def screenshot(self, client: viser.ClientHandle | None) -> Path | None:
        """Renders the client's view at the chosen resolution and saves it (and sends it to that browser)."""
        if client is None:
            return None
        request = self.request(client)
        picture = self.render(request, request.max_side)
        out = save_screenshot(self.out_dir, picture.rgb)
        client.send_file_download(out.name, out.read_bytes())
        client.add_notification("Screenshot", f"saved {out}", auto_close_seconds=5.0)
        return out

    def add_keyframe(self, client: viser.ClientHandle | None) -> None:
        if client is None:
            return
        camera = self.camera_of(client)
        self.keyframes.append(camera)
        wxyz, position = viser_pose(camera.c2w)
        self.server.scene.add_camera_frustum(f"/keyframes/{len(self.keyframes)}", fov=camera.fov_y,
                                             aspect=camera.aspect, scale=0.5 * frustum_scale(self.scene.bounds),
                                             color=(220, 30, 30), wxyz=wxyz, position=position)

    def clear_keyframes(self) -> None:
        for i in range(1, len(self.keyframes) + 1):
            self.server.scene.remove_by_name(f"/keyframes/{i}")
        self.keyframes = []

    def export_path(self, client: viser.ClientHandle | None) -> Path | None:
        """Saves the path through the keyframes (it needs at least two) and sends it to the browser."""
        if len(self.keyframes) < 2:
            if client is not None:
                client.add_notification("Camera path", "add at least two keyframes first", auto_close_seconds=5.0)
            return None
        # The train views' field of view and aspect: render_video builds its NDC from the frames' camera.
        fov, aspect = vertical_fov(self.train.intrinsics[0], self.train.height), self.train.width / self.train.height
        path = camera_path(self.keyframes, int(self.frames_per_segment.value), int(self.resolution.value),
                           float(self.fps.value), fov, aspect)
        out = save_camera_path(self.out_dir, path)
        if client is not None:
            client.send_file_download(out.name, out.read_bytes())
            client.add_notification("Camera path", f"saved {out} ({len(path.c2w)} frames)", auto_close_seconds=5.0)
        return out

    def close(self) -> None:
        for renderer in self.renderers.values():
            renderer.close()
        self.server.stop()
