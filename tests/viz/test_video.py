import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from simplenerf.data.llff import load_llff_scene
from simplenerf.model.nerf import NeRF, mlp_nerf
from simplenerf.viz.video import compose_frame, depth_colour_range, frame_rays, render_video, scale_intrinsics


def tiny_nerf() -> NeRF:
    torch.manual_seed(0)
    return mlp_nerf(num_coarse=4, num_fine=4, num_layers=2, width=8, skip_layer=1)


def mp4_codec(path: Path) -> str:
    """The fourcc of the first sample entry of an mp4's `stsd` box: `avc1` for H.264, `mp4v` for MPEG-4 part 2."""
    data = path.read_bytes()
    assert data[4:8] == b"ftyp", "not an mp4"
    i = data.index(b"stsd")  # [size]['stsd'][version+flags][entry count][entry size][format]
    return data[i + 16 : i + 20].decode("ascii")


def read_video(path: Path) -> list[np.ndarray]:
    """All frames, BGR [H, W, 3]."""
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    return frames


def test_scale_intrinsics_down_and_up():
    k = torch.tensor([[100.0, 0.0, 64.0], [0.0, 90.0, 48.0], [0.0, 0.0, 1.0]])
    scaled, h, w = scale_intrinsics(k, 96, 128, 0.25)
    assert torch.equal(scaled, torch.tensor([[25.0, 0.0, 16.0], [0.0, 22.5, 12.0], [0.0, 0.0, 1.0]]))
    assert (h, w) == (24, 32)
    scaled, h, w = scale_intrinsics(k, 96, 128, 2)  # larger than the data: a NeRF renders at any size
    assert torch.equal(scaled, torch.tensor([[200.0, 0.0, 128.0], [0.0, 180.0, 96.0], [0.0, 0.0, 1.0]]))
    assert (h, w) == (192, 256)
    with pytest.raises(ValueError, match="must be positive"):
        scale_intrinsics(k, 96, 128, 0)


def test_depth_range_and_frame_layout():
    depths = [np.array([[1.0, 2.0]]), np.array([[4.0, 4.0]])]
    assert depth_colour_range(depths, percentiles=(0.0, 100.0)) == pytest.approx((1.0, 4.0))
    rgb = np.zeros((3, 2, 3))
    rgb[..., 0] = 1.0
    frame = compose_frame(rgb, np.array([[1.0, 4.0]] * 3), (1.0, 4.0))
    assert frame.shape == (4, 4, 3) and frame.dtype == np.uint8  # odd height padded by repeating the last row
    assert (frame[:, :2] == [255, 0, 0]).all()
    assert np.array_equal(frame[3], frame[2])
    # inverse depth: the closest depth gets the top of the colour map, the farthest its bottom
    turbo = cv2.cvtColor(cv2.applyColorMap(np.array([[255, 0]], np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    assert np.array_equal(frame[0, 2:], turbo[0])


def test_frame_rays_are_row_major():
    k = torch.tensor([[10.0, 0.0, 2.0], [0.0, 10.0, 1.5], [0.0, 0.0, 1.0]])
    rays = frame_rays(torch.eye(3, 4), k, 3, 4, near=1.0)
    assert len(rays) == 12
    assert torch.allclose(rays.directions[5], torch.tensor([(1 - 2.0) / 10, -(1 - 1.5) / 10, -1.0]))  # u=1, v=1


def test_render_video_writes_rgb_beside_depth(synthetic_scene, tmp_path):
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    c2w = scene.trajectory("spiral", n_frames=8)
    h, w = scene.views.height, scene.views.width
    nerf = tiny_nerf()
    out, depth_range = render_video(nerf, c2w, scene.views.intrinsics[0], h, w, 1.0, 1024, tmp_path / "v.mp4",
                                    range_frames=3)
    assert out == tmp_path / "v.mp4" and sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    frames = read_video(out)
    assert len(frames) == 8 and frames[0].shape == (h, 2 * w, 3)
    # H.264 in yuv420p with the index first: what browsers and W&B play.
    assert mp4_codec(out) == "avc1"
    assert out.read_bytes().index(b"moov") < out.read_bytes().index(b"mdat")
    # left half: the deterministic render of the first pose (up to mp4 compression)
    expected = nerf.render_rays_chunked(frame_rays(c2w[0], scene.views.intrinsics[0], h, w, 1.0), 1024).rgb
    expected = np.round(expected.reshape(h, w, 3).numpy() * 255)
    left = cv2.cvtColor(frames[0][:, :w], cv2.COLOR_BGR2RGB).astype(np.float64)
    assert np.abs(left - expected).mean() < 4
    assert 0 < depth_range[0] <= depth_range[1]
    # a given range is used as is, e.g. to colour a second model's video the same way
    _, again = render_video(nerf, c2w[:2], scene.views.intrinsics[0], h, w, 1.0, 1024, tmp_path / "v2.mp4",
                            depth_range=(1.5, 6.0))
    assert again == (1.5, 6.0) and len(read_video(tmp_path / "v2.mp4")) == 2


def test_render_video_leaves_nothing_when_interrupted_or_unwritable(tmp_path, monkeypatch):
    nerf = tiny_nerf()
    k = torch.tensor([[20.0, 0.0, 8.0], [0.0, 20.0, 6.0], [0.0, 0.0, 1.0]])
    c2w = torch.eye(3, 4).expand(4, 3, 4)
    with pytest.raises(OSError, match="cannot open an H.264 video writer"):
        render_video(nerf, c2w, k, 12, 16, 1.0, 256, tmp_path / "v.unknown_container")
    calls = []
    original = nerf.render_rays_chunked

    def failing(rays, chunk):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return original(rays, chunk)

    monkeypatch.setattr(nerf, "render_rays_chunked", failing)
    with pytest.raises(KeyboardInterrupt):
        render_video(nerf, c2w, k, 12, 16, 1.0, 256, tmp_path / "v.mp4", range_frames=1)
    assert list(tmp_path.iterdir()) == []


def run_tool(*args: str) -> subprocess.CompletedProcess:
    from tests.run.test_cli import run

    return run("render-video", *args, check=False)


def test_render_video_verb_on_the_demo_config(tmp_path):
    from simplenerf.run.cli import make_cli
    from tests.run.test_cli import run_args

    args = run_args(tmp_path)
    cli = make_cli([*args, "--trainer.logger", "false"], run=False)  # an untrained model: its state dict will do
    ckpt = tmp_path / "model.ckpt"
    torch.save({"state_dict": cli.model.state_dict()}, ckpt)
    proc = run_tool("--config", "configs/demo.yaml", "--ckpt_path", str(ckpt), "--frames", "3", "--scale", "0.25",
                    *args[2:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / "run" / "video_spiral.mp4"  # default: the run folder, spiral for an LLFF-style scene
    assert f"video: {out} (3 frames of 64x24, spiral;" in proc.stdout
    frames = read_video(out)
    assert len(frames) == 3 and frames[0].shape == (24, 64, 3)


def test_render_video_verb_missing_checkpoint_is_one_line_error(tmp_path):
    proc = run_tool("--config", "configs/demo.yaml", "--ckpt_path", str(tmp_path / "nope.ckpt"))
    assert proc.returncode == 2
    expected = f"simplenerf: error: checkpoint {tmp_path / 'nope.ckpt'} does not exist"
    assert proc.stderr.strip().splitlines() == [expected]
