import re

import numpy as np
import pytest
import yaml

from simplenerf.viewer.camera import ViewerCamera, vertical_fov
from simplenerf.viewer.export import interpolate_path
from simplenerf.viewer.modes import RenderMode
from simplenerf.viewer.progressive import ProgressiveRenderer, RenderRequest
from simplenerf.viz.camera_path import read_camera_path
from tests.run.test_cli import run


def train_camera(viewer, view: int) -> ViewerCamera:
    train = viewer.train
    return ViewerCamera(train.c2w[view].double().numpy(), vertical_fov(train.intrinsics[view], train.height),
                        train.width / train.height)


def test_fit_with_the_viewer_prints_its_url_and_records_it(viewer_run):
    folder, stdout = viewer_run
    assert re.search(r"^viewer: open http://127\.0\.0\.1:\d+ in a browser to watch the training$", stdout, re.M)
    saved = yaml.safe_load((folder / "config.yaml").read_text())
    assert saved["viewer"] is True and saved["viewer_port"] == 0


def test_every_mode_renders_a_picture_of_the_requested_size(viewer):
    camera = train_camera(viewer, 1)  # the demo's pictures are 4:3
    labels = [m.label for m in viewer.modes]
    assert labels == ["RGB", "depth", "accumulation", "coarse | fine depth", "depth: points (augmented)",
                      "depth: views (augmented)", "mask: points", "mask: views", "mask: cfc"]
    for mode in viewer.modes:
        picture = viewer.render(RenderRequest(camera, mode, 40), 40)
        assert picture.rgb.shape == (30, 40, 3) and picture.rgb.dtype == np.uint8, mode.label
        assert picture.depth.shape == (30, 40) and (picture.depth > 0).all(), mode.label
        assert picture.rgb.std() > 0, f"{mode.label}: a constant picture"
    assert viewer.status.content.endswith(f"nearest train view 1 ({viewer.train.names[1]})")


def test_the_mask_of_the_nearest_train_view_is_the_models(viewer):
    # From a train view's own camera, each pixel's surface point projects back onto that pixel: the mask view is
    # the module's reliability map of that view, in the legend's colours.
    view = 2
    train = viewer.train
    camera = train_camera(viewer, view)
    mask = viewer.masks_of(view)["points"]
    picture = viewer.render(RenderRequest(camera, RenderMode("mask", "points"), train.width), train.width)
    rgb = viewer.render(RenderRequest(camera, RenderMode("rgb"), train.width), train.width).rgb / 255.0
    expected = {1: (0.1, 0.85, 0.2), -1: (0.9, 0.1, 0.8), 0: (0.5, 0.5, 0.5)}
    for value, colour in expected.items():
        where = (mask == value).cpu().numpy()
        blend = np.round((0.4 * rgb + 0.6 * np.array(colour)) * 255)
        agree = (np.abs(picture.rgb[where].astype(float) - blend[where]) <= 1).all(-1)
        assert agree.mean() > 0.95, (value, agree.mean())  # (rounding of reprojected pixels at depth edges)


def test_progressive_renders_of_the_viewer(viewer):
    shown = []
    renderer = ProgressiveRenderer(viewer.render, lambda p, r, final: shown.append((p.rgb.shape, final)))
    renderer.start()
    renderer.submit(RenderRequest(train_camera(viewer, 0), RenderMode("depth"), 64))
    assert renderer.idle.wait(60)
    renderer.close()
    assert shown == [((12, 16, 3), False), ((24, 32, 3), False), ((48, 64, 3), True)]


class FakeClient:
    """What the viewer's buttons use of a browser: its camera, downloads and notifications."""

    def __init__(self, camera) -> None:
        self.camera, self.downloads, self.notes = camera, [], []

    def send_file_download(self, name, content):
        self.downloads.append((name, content))

    def add_notification(self, title, body, **_):
        self.notes.append(body)


def client_at(viewer, view: int) -> FakeClient:
    from simplenerf.viewer.camera import viser_pose

    camera = train_camera(viewer, view)
    wxyz, position = viser_pose(camera.c2w)
    return FakeClient(type("Camera", (), {"wxyz": wxyz, "position": position, "fov": camera.fov_y,
                                          "aspect": camera.aspect})())


def test_screenshot_and_camera_path_export(viewer, viewer_run, tmp_path):
    viewer.out_dir = tmp_path / "viewer"
    client = client_at(viewer, 0)
    shot = viewer.screenshot(client)
    assert shot == tmp_path / "viewer" / "screenshot_1.png" and client.downloads[0][0] == "screenshot_1.png"
    assert viewer.export_path(client) is None and client.notes[-1] == "add at least two keyframes first"
    viewer.add_keyframe(client)
    viewer.add_keyframe(client_at(viewer, 2))
    viewer.frames_per_segment.value = 4
    out = viewer.export_path(client)
    path = read_camera_path(out)
    assert out.name == "camera_path_1.json" and len(path.c2w) == 5
    assert np.allclose(path.c2w[0].numpy(), viewer.train.c2w[0].double().numpy(), atol=1e-6)
    assert np.allclose(path.c2w[-1].numpy(), viewer.train.c2w[2].double().numpy(), atol=1e-6)
    assert (path.width, path.height) == (int(viewer.resolution.value), int(viewer.resolution.value) * 3 // 4)
    viewer.clear_keyframes()
    assert viewer.keyframes == []

    # render-video takes the exported path: one frame per pose
    folder, video = viewer_run[0], tmp_path / "path.mp4"
    proc = run("render-video", "--config", str(folder / "config.yaml"), "--ckpt_path",
               str(folder / "checkpoints" / "last.ckpt"), "--trajectory", str(out), "--scale", "0.25", "--out",
               str(video), check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"video: {video} (5 frames of " in proc.stdout and video.stat().st_size > 0


def test_interpolated_path_is_slerp_between_keyframes():
    a = ViewerCamera(np.eye(3, 4), 1.0, 1.0)
    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # 90 degrees about y
    b = ViewerCamera(np.concatenate([turn, [[2.0], [0.0], [0.0]]], axis=1), 1.0, 1.0)
    poses = interpolate_path([a, b], 2)
    half = np.sqrt(0.5)
    assert poses.shape == (3, 3, 4)
    assert np.allclose(poses[1], [[half, 0, half, 1.0], [0, 1, 0, 0], [-half, 0, half, 0]])
    assert np.allclose(poses[2], b.c2w)
    with pytest.raises(ValueError, match="at least one keyframe"):
        interpolate_path([], 2)


def test_a_wider_canvas_shows_the_same_scene_with_more_at_the_sides(viewer):
    # Same pose and vertical field of view, 160 instead of 128 pixels across: the middle 128 columns are the same
    # rays, so the same picture (the NDC is the data's, not the canvas').
    camera = train_camera(viewer, 0)
    wide = ViewerCamera(camera.c2w, camera.fov_y, 160 / 96)
    narrow = viewer.render(RenderRequest(camera, RenderMode("rgb"), 128), 128).rgb
    wider = viewer.render(RenderRequest(wide, RenderMode("rgb"), 160), 160).rgb
    assert narrow.shape == (96, 128, 3) and wider.shape == (96, 160, 3)
    assert np.abs(wider[:, 16:144].astype(int) - narrow.astype(int)).max() <= 1
