import shutil

import numpy as np
import pytest
import torch

from simplenerf.data.llff import LLFFDataModule, llff_split, load_llff_scene
from simplenerf.errors import DataError
from simplenerf.geometry.rays import ndc_to_metric_t, project
from tests.conftest import require_shared

# Frame counts and the train frames of the release's TrainTestCreator01_UniformSparseSampling.py (original numbers).
FRAME_COUNTS = {"fern": 20, "flower": 34, "fortress": 42, "horns": 62, "leaves": 26, "orchids": 25, "room": 41,
                "trex": 55}
TRAIN_FRAMES = {
    ("fern", 2): [6, 13], ("fern", 3): [5, 10, 14], ("fern", 4): [4, 7, 12, 15],
    ("horns", 2): [20, 42], ("horns", 3): [15, 30, 46], ("horns", 4): [12, 25, 37, 50],
    ("flower", 2): [11, 22], ("fortress", 2): [13, 28], ("leaves", 2): [9, 17], ("orchids", 2): [7, 17],
    ("room", 2): [13, 27], ("trex", 2): [18, 37],
}


@pytest.mark.parametrize("scene,n_views", sorted(TRAIN_FRAMES))
def test_split_reproduces_the_paper_table(scene, n_views):
    split = llff_split(FRAME_COUNTS[scene], n_views)
    assert split.train == TRAIN_FRAMES[scene, n_views]
    assert split.test == list(range(0, FRAME_COUNTS[scene], 8))
    assert split.val == [split.test[len(split.test) // 2]]
    assert not set(split.train) & set(split.test)


def test_dense_split_trains_on_every_non_test_frame():
    split = llff_split(20, None)
    assert split.test == [0, 8, 16] and split.val == [8]
    assert split.train == [i for i in range(20) if i % 8]
    assert split.test == llff_split(20, 2).test  # the same test frames as every few-view split


def test_dense_data_module_loads_every_non_test_frame(synthetic_scene):
    dm = LLFFDataModule(str(synthetic_scene), n_views=None, factor=1, rays_per_batch=100)
    dm.setup("fit")
    assert len(dm.train_views) == 17 and dm.scene.split.test == [0, 8, 16]
    assert dm.train_views.depths is not None  # the synthetic scene's exact depth, as for few views


def test_fern_loads_with_scaled_bounds():
    fern = require_shared("data/nerf_llff_data/fern")
    scene = load_llff_scene(fern, factor=8, n_views=2)
    assert scene.views.images.shape == (20, 378, 504, 3)
    assert scene.split.train == [6, 13]
    # min train bound is 0.75 after scaling, so NDC near = 1 is in front of every train camera.
    assert scene.bounds[scene.split.train].min() == pytest.approx(1 / 0.75)
    assert scene.views.intrinsics[0, 0, 2] == 252 and scene.views.intrinsics[0, 1, 2] == 189
    # Recentred on the average train pose: train camera centres average to the origin.
    assert torch.allclose(scene.views.c2w[scene.split.train, :, 3].mean(0), torch.zeros(3), atol=1e-5)


def test_synthetic_rays_hit_the_known_depth(synthetic_scene):
    """A pixel's ray at its exact depth reprojects into another view where that view's exact depth agrees."""
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views, (a, b) = scene.views, scene.split.train
    h, w = views.height, views.width
    v, u = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    uv = torch.stack([u.flatten(), v.flatten()], -1)
    batch = views.rays(torch.full((h * w,), a), uv, near=1.0)
    points = batch.origins + views.depths[a].reshape(-1, 1) * batch.directions
    uv_b, z_b = project(points, views.intrinsics[b : b + 1], views.c2w[b : b + 1])
    # Inverse depth is affine in image coordinates on a plane, so bilinear interpolation of view b's inverse depth
    # is exact wherever the 4 neighbouring pixels see the same plane.
    inside = (uv_b[:, 0] >= 0) & (uv_b[:, 0] < w - 1) & (uv_b[:, 1] >= 0) & (uv_b[:, 1] < h - 1)
    uv_in, z_in = uv_b[inside], z_b[inside]
    x0, y0 = uv_in.floor().long().unbind(-1)
    fx, fy = (uv_in - uv_in.floor()).unbind(-1)
    inv = 1.0 / views.depths[b]
    inv_b = (inv[y0, x0] * (1 - fx) * (1 - fy) + inv[y0, x0 + 1] * fx * (1 - fy)
             + inv[y0 + 1, x0] * (1 - fx) * fy + inv[y0 + 1, x0 + 1] * fx * fy)
    agree = (inv_b * z_in - 1).abs() < 1e-4
    assert inside.sum() > 0.5 * h * w
    # Most points are seen by view b at exactly the reprojected depth; the rest are occluded or at depth edges.
    assert agree.float().mean() > 0.8


def test_ndc_samples_recover_the_exact_depth(synthetic_scene):
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = scene.views
    uv = torch.tensor([[5, 5], [30, 20], [60, 40]])
    rays = views.rays(torch.zeros(3, dtype=torch.long), uv, near=1.0)
    depth = views.depths[0][uv[:, 1], uv[:, 0]]
    # The NDC t of the surface, mapped back, is the exact depth.
    world_z = rays.origins[:, 2] + depth * rays.directions[:, 2]
    z_ndc = 1 + 2.0 / world_z
    t_ndc = (z_ndc - rays.ndc_origins[:, 2]) / rays.ndc_directions[:, 2]
    assert torch.allclose(ndc_to_metric_t(t_ndc[:, None], rays, 1.0)[:, 0], depth, rtol=1e-4)


def test_training_batches_are_consistent_with_images(synthetic_scene):
    dm = LLFFDataModule(str(synthetic_scene), n_views=3, factor=1, rays_per_batch=100)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    train = dm.train_views
    rays = batch.random
    assert rays.rgb.shape == (100, 3) and batch.sparse is None
    assert torch.equal(rays.rgb, train.images[rays.view, rays.uv[:, 1], rays.uv[:, 0]])
    frame = dm.test_dataloader().dataset[0]
    assert frame.rgb.shape == (48 * 64, 3) and frame.depth.shape == (48 * 64,)


def copy_scene(src, dst):
    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize(
    "breakage,message",
    [
        ("no_dir", "does not exist"),
        ("no_poses", "poses_bounds.npy is missing"),
        ("extra_image", "has 21 images but"),
        ("bad_image", "cannot read image"),
        ("no_images", "images_4 is missing"),
    ],
)
def test_bad_scenes_give_clear_errors(synthetic_scene, tmp_path, breakage, message):
    scene = copy_scene(synthetic_scene, tmp_path / "scene")
    factor = 1
    if breakage == "no_dir":
        scene = tmp_path / "nowhere"
    elif breakage == "no_poses":
        (scene / "poses_bounds.npy").unlink()
    elif breakage == "extra_image":
        shutil.copy(scene / "images" / "000.png", scene / "images" / "999.png")
    elif breakage == "bad_image":
        (scene / "images" / "003.png").write_bytes(b"not a png")
    elif breakage == "no_images":
        factor = 4
    with pytest.raises(DataError, match=message):
        LLFFDataModule(str(scene), factor=factor).load_scene()


def test_too_many_views_is_an_error(synthetic_scene):
    with pytest.raises(DataError, match="n_views=18 is not possible: the train pool has 17 frames"):
        LLFFDataModule(str(synthetic_scene), factor=1, n_views=18).setup("fit")


def test_bounds_come_from_train_frames_only(synthetic_scene, tmp_path):
    scene = copy_scene(synthetic_scene, tmp_path / "scene")
    pb = np.load(scene / "poses_bounds.npy")
    pb[0, 15] = 0.01  # a test frame with a tiny near bound must not change the scale
    np.save(scene / "poses_bounds.npy", pb)
    a = load_llff_scene(synthetic_scene, 1, 2)
    b = load_llff_scene(scene, 1, 2)
    assert a.scale == b.scale


def test_sparse_depth_rays_carry_sfm_depth(tmp_path):
    """Sparse-depth rays sit on SfM keypoints of the train views and carry their depth (checked against exact depth)."""
    from simplenerf.data.synthetic import SyntheticDataModule

    dm = SyntheticDataModule(root=str(tmp_path / "data"), height=240, width=320, n_frames=8, n_views=2,
                             rays_per_batch=64, sparse_rays_per_batch=256, sparse_depth_cache=str(tmp_path / "cache"))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    sparse = batch.sparse
    assert batch.random.rgb.shape == (64, 3) and sparse.depth.shape == (256,)
    assert torch.equal(sparse.weight, torch.ones(256))  # DS-NeRF weighting is off by default
    train = dm.train_views
    pix = torch.round(dm.sparse_depth.uv).long()
    exact = train.depths[dm.sparse_depth.view, pix[:, 1], pix[:, 0]]
    assert (dm.sparse_depth.depth / exact - 1).abs().median() < 0.01
    # The ray of a sparse sample at its SfM depth is the 3D point: it projects back onto its keypoint.
    points = sparse.rays.origins + sparse.depth[:, None] * sparse.rays.directions
    uv, z = project(points, train.intrinsics[sparse.view], train.c2w[sparse.view])
    assert torch.allclose(z, sparse.depth, rtol=1e-5)
    assert list((tmp_path / "cache").glob("*.json")), "sparse depth was not cached"


def test_a_moved_scene_reuses_its_cached_sparse_depth(tmp_path, monkeypatch):
    """The sparse-depth cache is keyed by the images and cameras, not by the scene's folder: the same scene in another
    folder loads the cached SfM result instead of running SfM again."""
    import simplenerf.sfm.sparse_depth as sparse_depth
    from simplenerf.data.synthetic import SyntheticDataModule

    def module(root):
        return SyntheticDataModule(root=str(root), height=120, width=160, n_frames=8, n_views=2, rays_per_batch=64,
                                   sparse_rays_per_batch=64, sparse_depth_cache=str(tmp_path / "cache"))

    first = module(tmp_path / "a")
    first.setup("fit")

    def no_sfm(*args, **kwargs):
        raise AssertionError("SfM ran again for a scene already in the cache")

    monkeypatch.setattr(sparse_depth, "compute_sparse_depth", no_sfm)
    moved = module(tmp_path / "b")
    moved.setup("fit")
    assert moved.scene.source != first.scene.source
    assert torch.equal(moved.sparse_depth.depth, first.sparse_depth.depth)
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 1
