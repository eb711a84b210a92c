"""Reference-depth export: one file-unit depth map per frame, read back by `reference_depth_dir` at any split."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from simplenerf.data.llff import LLFFDataModule, load_llff_scene
from simplenerf.errors import DataError
from simplenerf.evaluation.reference_depth import export_reference_depth
from simplenerf.model.nerf import mlp_nerf


def test_export_writes_every_frame_and_loads_back_scaled(synthetic_scene, tmp_path):
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    torch.manual_seed(0)
    nerf = mlp_nerf(num_coarse=4, num_fine=4, num_layers=2, width=16, skip_layer=1)
    paths = export_reference_depth(nerf, scene, near=1.0, chunk=1000, out_dir=tmp_path / "depth")
    assert [p.name for p in paths] == [f"{i:03d}.npy" for i in range(20)]  # train and test frames alike
    assert sorted(p.name for p in (tmp_path / "depth").iterdir()) == [p.name for p in paths]
    depth = np.load(paths[3])
    assert depth.shape == (48, 64) and depth.dtype == np.float32 and np.isfinite(depth).all()

    dm = LLFFDataModule(str(synthetic_scene), n_views=2, factor=1, reference_depth_dir=str(tmp_path / "depth"))
    dm.setup("test")
    files = np.stack([np.load(p) for p in paths])
    expected = torch.from_numpy(files * dm.scene.scale).to(dm.scene.views.depths.dtype)
    assert torch.equal(dm.scene.views.depths, expected)
    assert not torch.allclose(dm.scene.views.depths, scene.views.depths)  # the exact depth was not used


class ExactDepth(nn.Module):
    """A stand-in NeRF that renders the scene's exact depth (scene units), frame after frame."""

    def __init__(self, depths: torch.Tensor) -> None:
        super().__init__()
        self.depths, self.frame = depths, 0
        self.dummy = nn.Parameter(torch.zeros(()))  # where to render

    def render_rays_chunked(self, rays, chunk: int) -> SimpleNamespace:
        depth = self.depths[self.frame].reshape(-1)
        assert len(rays) == depth.numel()
        self.frame += 1
        return SimpleNamespace(depth=depth)


def test_export_is_in_file_units_so_any_split_reads_it(synthetic_scene, tmp_path):
    """Depth exported from the 2-view scene, loaded with 3 views (another scale), is that split's exact depth."""
    two, three = (load_llff_scene(synthetic_scene, factor=1, n_views=n) for n in (2, 3))
    assert two.scale != pytest.approx(three.scale)  # train bounds differ, so the test can fail
    export_reference_depth(ExactDepth(two.views.depths), two, near=1.0, chunk=1000, out_dir=tmp_path)
    loaded = load_llff_scene(synthetic_scene, factor=1, n_views=3, reference_depth_dir=tmp_path)
    assert torch.allclose(loaded.views.depths, three.views.depths, rtol=1e-6)


def test_bad_reference_depth_is_a_clear_error(synthetic_scene, tmp_path):
    with pytest.raises(DataError, match="reference depth folder .*nowhere does not exist"):
        load_llff_scene(synthetic_scene, factor=1, n_views=2, reference_depth_dir=tmp_path / "nowhere")
    for i in range(20):
        np.save(tmp_path / f"{i:03d}.npy", np.ones((48, 64), np.float32))
    np.save(tmp_path / "007.npy", np.ones((64, 48), np.float32))
    with pytest.raises(DataError, match=r"007\.npy has shape \(64, 48\), expected the frame's \(48, 64\)"):
        load_llff_scene(synthetic_scene, factor=1, n_views=2, reference_depth_dir=tmp_path)
    (tmp_path / "019.npy").unlink()
    np.save(tmp_path / "007.npy", np.ones((48, 64), np.float32))
    with pytest.raises(DataError, match=r"019\.npy is missing: the reference depth folder needs one"):
        LLFFDataModule(str(synthetic_scene), factor=1, reference_depth_dir=str(tmp_path)).setup("test")
