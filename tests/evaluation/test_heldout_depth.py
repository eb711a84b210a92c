"""Depth error at held-out keypoints: of the fine depth, and of every depth the model renders."""

import numpy as np
import pytest
import torch

from simplenerf.data.synthetic import SyntheticDataModule
from simplenerf.evaluation.heldout_depth import heldout_depth_error
from simplenerf.sfm.sparse_depth import SparseDepth
from tests.method.test_module import simplenerf_module


def _keypoints_of_a_heldout_frame(tmp_path):
    """A synthetic scene 64 pixels wide, a module, one held-out frame and five keypoints at known columns of it (3.5,
    20, 40.25, 63, 31.5), with their rays."""
    dm = SyntheticDataModule(root=str(tmp_path / "data"), height=48, width=64, n_frames=8, n_views=2,
                             sparse_rays_per_batch=0)
    dm.setup("test")
    scene = dm.scene
    frame = next(i for i in range(8) if i not in scene.split.train and i not in scene.split.test)
    pixels = np.array([[3.5, 4.5], [20.0, 30.0], [40.25, 10.0], [63.0, 47.0], [31.5, 23.5]], np.float32)
    rays = scene.views.rays(torch.full((5,), frame), torch.from_numpy(pixels).to(scene.views.c2w.dtype), dm.near)
    return dm, simplenerf_module().eval(), frame, pixels, rays


def test_every_rendered_depth_is_scored_at_the_keypoints(tmp_path):
    dm, model, frame, pixels, rays = _keypoints_of_a_heldout_frame(tmp_path)
    scene = dm.scene
    with torch.no_grad():
        renders = model.render(rays, randomized=False)
    fine = renders.main.fine.depth.double()
    reference = 2 * fine  # the fine depth is off by exactly a half everywhere
    sd = SparseDepth(pixels, reference.float().numpy(), np.zeros(5, np.float32), np.arange(5))
    result = heldout_depth_error(model, scene, {frame: sd}, dm.near, chunk=2)
    sd_depth = torch.from_numpy(sd.depth).double()
    expected = {"fine": fine, "coarse": renders.main.coarse.depth.double(),
                **{name: r.depth.double() for name, r in renders.augmented.items()}}
    assert set(result["depths"]) == {"fine", "coarse", "points", "views"}
    for name, depth in expected.items():
        error = (depth - sd_depth).abs() / sd_depth
        assert result["depths"][name]["rel_error_mean"] == pytest.approx(float(error.mean()), rel=1e-5)
        assert result["depths"][name]["rel_error_median"] == pytest.approx(float(error.median()), rel=1e-5)
    assert result["rel_error_mean"] == pytest.approx(0.5, rel=1e-6) and result["points"] == 5 and result["frames"] == 1
    # the augmented fields differ from the main ones, so their errors do too
    assert result["depths"]["points"]["rel_error_mean"] != result["depths"]["coarse"]["rel_error_mean"]


def test_untrained_augmentations_are_left_out_and_named(tmp_path):
    """An augmentation retired from step 0 (e.g. the ablation without L_ap) is not rendered or scored: "depths" has
    the others, with the same numbers as when all are scored, and "untrained" names it; an unknown name is refused."""
    dm, model, frame, pixels, rays = _keypoints_of_a_heldout_frame(tmp_path)
    sd = SparseDepth(pixels, np.full(5, 2.0, np.float32), np.zeros(5, np.float32), np.arange(5))
    every = heldout_depth_error(model, dm.scene, {frame: sd}, dm.near, chunk=2)
    without = heldout_depth_error(model, dm.scene, {frame: sd}, dm.near, chunk=2, untrained={"points"})
    assert every["untrained"] == [] and without["untrained"] == ["points"]
    assert set(without["depths"]) == {"fine", "coarse", "views"}
    assert all(without["depths"][name] == every["depths"][name] for name in ("fine", "coarse", "views"))
    with pytest.raises(ValueError, match=r"untrained names \['pints'\], not among"):
        heldout_depth_error(model, dm.scene, {frame: sd}, dm.near, untrained={"pints"})


def test_a_moved_scene_reuses_its_cached_heldout_reference(tmp_path, monkeypatch):
    """The held-out reference (SfM from every non-test frame) is cached by the images and cameras, not by the scene's
    folder: the same scene in another folder loads it instead of running SfM again."""
    import simplenerf.sfm.sparse_depth as sparse_depth
    from simplenerf.evaluation.heldout_depth import heldout_observations

    def scene(root):
        dm = SyntheticDataModule(root=str(root), height=120, width=160, n_frames=8, n_views=2,
                                 sparse_rays_per_batch=0)
        dm.setup("test")
        return dm.scene

    first = heldout_observations(scene(tmp_path / "a"), str(tmp_path / "cache"))
    assert first, "the synthetic scene gives no held-out SfM points"

    def no_sfm(*args, **kwargs):
        raise AssertionError("SfM ran again for a scene already in the cache")

    monkeypatch.setattr(sparse_depth, "compute_sparse_depth", no_sfm)
    moved = heldout_observations(scene(tmp_path / "b"), str(tmp_path / "cache"))
    assert sorted(moved) == sorted(first)
    assert all(np.array_equal(moved[f].depth, first[f].depth) for f in first)
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 1


def test_strips_say_where_the_error_is_and_whether_surfaces_were_pushed_back(tmp_path):
    """Keypoints at known columns of a 64-pixel-wide frame, with references set so that the fine depth is half the
    reference (in front: error 0.5) or twice it (behind: error 1.0); each strip's count, mean and behind-share are
    those numbers exactly, and an empty strip has no mean."""
    dm, model, frame, pixels, rays = _keypoints_of_a_heldout_frame(tmp_path)
    scene = dm.scene
    with torch.no_grad():
        fine = model.render(rays, randomized=False).main.fine.depth.double()
    behind = torch.tensor([False, True, False, True, False])
    reference = torch.where(behind, fine / 2, fine * 2)
    sd = SparseDepth(pixels, reference.float().numpy(), np.zeros(5, np.float32), np.arange(5))

    quarters = heldout_depth_error(model, scene, {frame: sd}, dm.near, chunk=2)["strips"]
    assert quarters["points"] == [1, 2, 1, 1]  # columns 3.5 | 20, 31.5 | 40.25 | 63 of 0-16-32-48-64
    assert quarters["rel_error_mean"] == pytest.approx([0.5, 0.75, 0.5, 1.0], rel=1e-5)
    assert quarters["behind_share"] == pytest.approx([0.0, 2 / 3, 0.0, 1.0], rel=1e-5)

    eighths = heldout_depth_error(model, scene, {frame: sd}, dm.near, chunk=2, strips=8)["strips"]
    assert eighths["points"] == [1, 0, 1, 1, 0, 1, 0, 1]
    assert eighths["rel_error_mean"][1] is None and eighths["behind_share"][1] is None
    assert eighths["rel_error_mean"][3] == pytest.approx(0.5, rel=1e-5)

    with pytest.raises(ValueError, match="strips must be at least 1"):
        heldout_depth_error(model, scene, {frame: sd}, dm.near, strips=0)


def test_the_command_refuses_fewer_than_one_strip_before_loading_anything(capsys):
    from simplenerf.commands.heldout_depth import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--config", "missing.yaml", "--ckpt_path", "missing.ckpt", "--strips", "0"])
    assert exit_info.value.code == 2
    assert "--strips must be at least 1, got 0" in capsys.readouterr().err
