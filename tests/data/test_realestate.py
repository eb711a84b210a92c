"""RealEstate-10K: the paper's split, the camera file (OpenCV world-to-camera -> our OpenGL camera-to-world), clear
errors for bad input, the project's copy of scene 000c3ab189999a83 and a reduced fit through the real CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from simplenerf.data.realestate import (
    RealEstateDataModule,
    load_realestate_scene,
    opencv_w2c_to_opengl_c2w,
    realestate_split,
)
from simplenerf.errors import DataError
from simplenerf.geometry.rays import pixel_rays, project
from tests.conftest import require_shared
from tests.run.test_cli import SMALL, run, tiny_model

SCENE = "data/realestate10k/000c3ab189999a83"


def frames(*ranges: tuple[int, int]) -> list[int]:
    """Inclusive ranges, as the paper's table writes them."""
    return [i for lo, hi in ranges for i in range(lo, hi + 1)]


# The paper's supplement, "Train and test frame numbers of RealEstate-10K dataset".
PAPER_SPLITS = {
    2: ([10, 20], frames((5, 9), (11, 19), (21, 25))),
    3: ([10, 20, 30], frames((5, 9), (11, 19), (21, 29), (31, 35))),
    4: ([0, 10, 20, 30], frames((1, 9), (11, 19), (21, 29), (31, 35))),
}


@pytest.mark.parametrize("n_views,size", [(2, 19), (3, 28), (4, 32)])
def test_split_reproduces_the_paper_table(n_views, size):
    split = realestate_split(n_views)
    train, test = PAPER_SPLITS[n_views]
    assert split.train == train and split.test == test and len(split.test) == size
    assert split.val == [test[size // 2]]


@pytest.mark.parametrize("split_views", [2, 3, 4])
def test_dense_split_trains_on_everything_but_the_test_frames(split_views):
    split = realestate_split(None, split_views=split_views)
    sparse = realestate_split(split_views)
    assert split.test == sparse.test and split.val == sparse.val
    assert split.train == sorted(set(range(50)) - set(sparse.test))
    assert set(sparse.train) <= set(split.train)
    assert len(split.train) == {2: 31, 3: 22, 4: 18}[split_views]


def test_impossible_splits_are_errors():
    with pytest.raises(DataError, match="n_views=5 is not possible on RealEstate-10K"):
        realestate_split(5)
    with pytest.raises(DataError, match="clip_length=25 is too short for 3 views: frame 30 trains"):
        realestate_split(3, clip_length=25)


def test_identity_world_to_camera_is_an_opengl_camera_at_the_origin():
    c2w = opencv_w2c_to_opengl_c2w(np.eye(3, 4)[None])
    assert np.array_equal(c2w[0], np.array([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0]]))


def random_w2c(rng: np.random.Generator) -> np.ndarray:
    """A world-to-camera [3, 4]: a rotation of up to ~0.3 rad about a random axis and a translation."""
    rotation, _ = cv2.Rodrigues(rng.normal(0, 0.15, 3))
    return np.concatenate([rotation, rng.normal(0, 0.5, (3, 1))], axis=1)


def opencv_project(w2c: np.ndarray, k: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, float]:
    """The dataset's own convention: x = R X + t, u = fx x / z + cx, v = fy y / z + cy."""
    x = w2c[:, :3] @ point + w2c[:, 3]
    return np.array([k[0, 0] * x[0] / x[2] + k[0, 2], k[1, 1] * x[1] / x[2] + k[1, 2]]), x[2]


def test_converted_camera_projects_like_the_opencv_camera():
    rng = np.random.default_rng(0)
    k = np.array([[50.0, 0, 6.5], [0, 40.0, 4.0], [0, 0, 1]])
    for _ in range(5):
        w2c = random_w2c(rng)
        point = np.linalg.inv(w2c[:, :3]) @ (rng.uniform([-1, -1, 2], [1, 1, 6]) - w2c[:, 3])  # in front
        uv_cv, z_cv = opencv_project(w2c, k, point)
        c2w = torch.from_numpy(opencv_w2c_to_opengl_c2w(w2c[None]))
        uv, z = project(torch.from_numpy(point)[None], torch.from_numpy(k)[None], c2w)
        assert np.allclose(uv[0].numpy(), uv_cv) and z.item() == pytest.approx(z_cv)


HEIGHT, WIDTH = 8, 12  # not square: width and height must not be swapped
NORMALISED = (0.9, 1.2, 0.5, 0.5)  # fx / W, fy / H, cx / W, cy / H


def write_clip(root: Path, n_frames: int = 52, seed: int = 0) -> tuple[Path, list[np.ndarray]]:
    """A RealEstate-10K-style video folder: camera file + PNG frames whose colour encodes the frame line."""
    rng = np.random.default_rng(seed)
    scene = root / "abc123"
    (scene / "frames").mkdir(parents=True)
    lines, poses = ["https://www.youtube.com/watch?v=xyz"], []
    for i in range(n_frames):
        w2c = random_w2c(rng)
        w2c[:, 3] *= 0.1
        poses.append(w2c)
        timestamp = 1000 + 33367 * i
        lines.append(" ".join([str(timestamp), *(f"{x:.9f}" for x in NORMALISED), "0", "0",
                               *(f"{x:.9f}" for x in w2c.reshape(-1))]))
        cv2.imwrite(str(scene / "frames" / f"{timestamp}.png"), np.full((HEIGHT, WIDTH, 3), i, np.uint8))
    (scene / "abc123.txt").write_text("\n".join(lines) + "\n")
    # What the file holds (9 decimals) is the truth the loader must reproduce.
    poses = [np.array([float(x) for x in line.split()[7:]]).reshape(3, 4) for line in lines[1:]]
    return scene, poses


def test_clip_loads_in_our_conventions(tmp_path):
    scene_dir, poses = write_clip(tmp_path)
    scene = load_realestate_scene(scene_dir, n_views=3, clip_start=1)
    assert scene.source == scene_dir and scene.camera_path == "recorded"  # a clip's video follows its own cameras
    views = scene.views
    assert views.images.shape == (50, HEIGHT, WIDTH, 3)
    # Frame k of the clip is line 1 + k of the camera file (clip_start=1), with its own image.
    assert views.names[0] == str(1000 + 33367) and views.names[-1] == str(1000 + 33367 * 50)
    assert torch.equal(views.images[:, 0, 0, 0] * 255, torch.arange(1, 51, dtype=views.images.dtype))
    k = np.array([[0.9 * WIDTH, 0, 0.5 * WIDTH], [0, 1.2 * HEIGHT, 0.5 * HEIGHT], [0, 0, 1]])
    assert torch.allclose(views.intrinsics, torch.from_numpy(k).to(views.intrinsics.dtype).expand(50, 3, 3))
    assert scene.scale == pytest.approx(4 / 3)
    assert np.allclose(scene.bounds, [[4 / 3, 400 / 3]] * 50)
    assert torch.allclose(views.c2w[scene.split.train, :, 3].mean(0), torch.zeros(3), atol=1e-6)
    # Scaling and recentring are a similarity: a point seen by clip frame a at OpenCV pixel uv and depth z is, at
    # depth z * scale along our ray through uv, the point that frame b sees where OpenCV's camera b sees it.
    rng = np.random.default_rng(1)
    ks = views.intrinsics.double()
    c2w = views.c2w.double()
    for a, b in [(0, 10), (10, 20), (20, 49)]:
        w2c_a, w2c_b = poses[1 + a], poses[1 + b]
        point = np.linalg.inv(w2c_a[:, :3]) @ (rng.uniform([-0.5, -0.5, 3], [0.5, 0.5, 5]) - w2c_a[:, 3])
        uv_a, z_a = opencv_project(w2c_a, k, point)
        uv_b, z_b = opencv_project(w2c_b, k, point)
        origin, direction = pixel_rays(ks[a : a + 1], c2w[a : a + 1], torch.from_numpy(uv_a)[None])
        ours = origin + z_a * scene.scale * direction
        uv, z = project(ours, ks[b : b + 1], c2w[b : b + 1])
        assert np.allclose(uv[0].numpy(), uv_b, atol=1e-4)
        assert z.item() == pytest.approx(z_b * scene.scale, rel=1e-5)


def test_reference_depth_is_read_in_file_units(tmp_path):
    scene_dir, _ = write_clip(tmp_path)
    depth_dir = tmp_path / "depth"
    depth_dir.mkdir()
    names = load_realestate_scene(scene_dir, n_views=2).views.names
    for i, name in enumerate(names):
        np.save(depth_dir / f"{name}.npy", np.full((HEIGHT, WIDTH), 2.0 + i, np.float32))
    dm = RealEstateDataModule(str(scene_dir), n_views=2, reference_depth_dir=str(depth_dir))
    dm.setup("test")
    assert torch.allclose(dm.scene.views.depths[:, 0, 0], (2.0 + torch.arange(50.0)) * 4 / 3)
    assert RealEstateDataModule(str(scene_dir)).load_scene().views.depths is None  # default: no depth


def break_line(scene: Path, line: int, new: str) -> None:
    camera_file = scene / "abc123.txt"
    lines = camera_file.read_text().splitlines()
    lines[line - 1] = new
    camera_file.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "breakage,message",
    [
        ("no_dir", "scene directory .* does not exist"),
        ("no_camera_file", r"camera file .*abc123\.txt is missing"),
        ("no_frames", r"frames folder .*frames is missing"),
        ("short_line", r"abc123\.txt line 5: expected 19 fields .* got 18"),
        ("not_a_number", r"abc123\.txt line 3: expected numbers after the timestamp"),
        ("missing_frame", r"has no frame 1000\.png for timestamp 1000 of .*abc123\.txt"),
        ("too_few_frames", r"abc123\.txt has 52 frames; the clip needs frames 5 to 54"),
        ("bad_views", "n_views=1 is not possible on RealEstate-10K"),
        ("bad_image", r"cannot read image .*1000\.png"),
    ],
)
def test_bad_input_gives_clear_errors(tmp_path, breakage, message):
    scene, _ = write_clip(tmp_path)
    args = {"n_views": 2}
    if breakage == "no_dir":
        scene = tmp_path / "nowhere"
    elif breakage == "no_camera_file":
        (scene / "abc123.txt").unlink()
    elif breakage == "no_frames":
        for p in (scene / "frames").iterdir():
            p.unlink()
        (scene / "frames").rmdir()
    elif breakage == "short_line":
        break_line(scene, 5, " ".join((scene / "abc123.txt").read_text().splitlines()[4].split()[:-1]))
    elif breakage == "not_a_number":
        break_line(scene, 3, (scene / "abc123.txt").read_text().splitlines()[2].replace("0.900000000", "0.9x"))
    elif breakage == "missing_frame":
        (scene / "frames" / "1000.png").unlink()
    elif breakage == "too_few_frames":
        args["clip_start"] = 5
    elif breakage == "bad_views":
        args["n_views"] = 1
    elif breakage == "bad_image":
        (scene / "frames" / "1000.png").write_bytes(b"not a png")
    with pytest.raises(DataError, match=message):
        RealEstateDataModule(str(scene), **args).setup("fit")


def test_project_scene_loads():
    scene_dir = require_shared(SCENE)
    scene = load_realestate_scene(scene_dir, n_views=2)
    assert scene.views.images.shape == (50, 256, 256, 3)
    assert scene.views.names[0] == "53453400"  # the first camera line
    assert scene.split.train == [10, 20] and len(scene.split.test) == 19
    # The crop's intrinsics: principal point at the centre (NDC assumes it), focal 0.857 * 256.
    assert torch.allclose(scene.views.intrinsics[0, :2, 2], torch.tensor([128.0, 128.0]))
    assert scene.views.intrinsics[0, 0, 0].item() == pytest.approx(0.857273717 * 256, rel=1e-6)


def test_project_scene_fits_through_the_cli(tmp_path):
    """3 steps of the paper config (tiny networks) on the project's scene: SfM on the 2 train views, then training."""
    scene_dir = require_shared(SCENE)
    out = str(tmp_path / "run")
    run(
        "fit", "--config", "configs/realestate.yaml", "--config", str(tiny_model(tmp_path)), *SMALL,
        "--data.init_args.scene_dir", str(scene_dir), "--data.init_args.sparse_depth_cache", str(tmp_path / "cache"),
        "--trainer.default_root_dir", out, "--trainer.logger.init_args.save_dir", out, "--trainer.max_steps", "3",
    )
    last = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3
    assert "augmentations.1.field.trunk.0.weight" in last["state_dict"]
    cached = [json.loads(p.read_text()) for p in (tmp_path / "cache").glob("*.json")]
    assert [c["key"]["views"] for c in cached] == [[10, 20]]  # SfM ran on the 2 train frames of the clip
