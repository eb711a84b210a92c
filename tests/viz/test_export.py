"""Geometry export (simplenerf.viz.export, `simplenerf export-geometry`): depth maps and a fused PLY point cloud, read
back with a minimal PLY reader."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from simplenerf.data.llff import load_llff_scene
from simplenerf.geometry.rays import pixel_grid, project
from simplenerf.model.nerf import mlp_nerf
from simplenerf.viz.export import export_geometry, lift_pixels, render_view, write_ply

PLY_TYPES = {"float": "<f4", "uchar": "u1"}


def read_ply(path: Path) -> np.ndarray:
    """The vertices of a binary little-endian PLY with one `vertex` element of float/uchar properties."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    elements = [line.split() for line in header if line.startswith("element")]
    assert len(elements) == 1 and elements[0][1] == "vertex"
    properties = [line.split()[1:] for line in header if line.startswith("property")]
    dtype = np.dtype([(name, PLY_TYPES[kind]) for kind, name in properties])
    assert len(data) - end == int(elements[0][2]) * dtype.itemsize  # nothing missing, nothing after the vertices
    return np.frombuffer(data[end:], dtype=dtype)


def test_write_ply_round_trip(tmp_path) -> None:
    xyz = np.array([[0.0, 1.5, -2.0], [1e3, -1e-3, 0.25]])
    rgb = np.array([[0, 128, 255], [7, 8, 9]], dtype=np.uint8)
    vertices = read_ply(write_ply(tmp_path / "p.ply", xyz, rgb))
    assert vertices.dtype.names == ("x", "y", "z", "red", "green", "blue")
    np.testing.assert_array_equal(np.stack([vertices[a] for a in "xyz"], 1), xyz.astype(np.float32))
    np.testing.assert_array_equal(np.stack([vertices[c] for c in ("red", "green", "blue")], 1), rgb)
    assert len(read_ply(write_ply(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros((0, 3), np.uint8)))) == 0
    with pytest.raises(ValueError, match="uint8 rgb"):
        write_ply(tmp_path / "bad.ply", xyz, rgb.astype(np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.ply", "p.ply"]  # no temporary file left


def test_lifted_pixels_project_back_onto_themselves(synthetic_scene) -> None:
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = scene.views
    k, c2w = views.intrinsics[3].double(), views.c2w[3].double()
    u, _, vt = torch.linalg.svd(c2w[:, :3])
    c2w[:, :3] = u @ vt  # an exact rotation in float64, so that projecting is exactly the inverse of lifting
    depth = np.random.default_rng(0).uniform(1.0, 5.0, (views.height, views.width))
    keep = depth > 2.0
    points = lift_pixels(depth, keep, k, c2w)
    uv, z = project(torch.from_numpy(points), k[None], c2w[None])
    expected_uv = pixel_grid(views.height, views.width)[torch.from_numpy(keep.ravel())].double()
    torch.testing.assert_close(uv, expected_uv, atol=1e-9, rtol=0)
    np.testing.assert_allclose(z.numpy(), depth[keep], atol=1e-12)


def test_export_of_a_tiny_model(synthetic_scene, tmp_path) -> None:
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = scene.views.subset(scene.split.train)
    torch.manual_seed(0)
    nerf = mlp_nerf(num_coarse=8, num_fine=8, num_layers=2, width=16, skip_layer=1)
    # What the export will render, to set a threshold that keeps some pixels and drops others.
    rendered = [render_view(nerf, views.c2w[i], views.intrinsics[i], views.height, views.width, 1.0, 1000)
                for i in range(len(views))]
    threshold = float(np.median(np.concatenate([r.accumulation.ravel() for r in rendered])))
    limits = [float(np.percentile(r.depth, 90)) for r in rendered]
    summary = export_geometry(nerf, views, 1.0, 1000, tmp_path / "geometry", min_accumulation=threshold,
                              max_depth=limits, scale=scene.scale)

    keeps = [(r.accumulation > threshold) & (r.depth <= limit) for r, limit in zip(rendered, limits, strict=True)]
    vertices = read_ply(tmp_path / "geometry" / "points.ply")
    expected_count = sum(int(k.sum()) for k in keeps)
    assert 0 < expected_count < views.height * views.width * len(views)
    assert len(vertices) == expected_count == summary["points"]
    xyz = np.stack([vertices[a] for a in "xyz"], 1)
    assert np.isfinite(xyz).all()
    expected_xyz = np.concatenate([lift_pixels(r.depth, k, views.intrinsics[i], views.c2w[i])
                                   for i, (r, k) in enumerate(zip(rendered, keeps, strict=True))])
    np.testing.assert_allclose(xyz, expected_xyz.astype(np.float32), rtol=1e-6, atol=1e-6)
    # Colours are the photos' own at the kept pixels (so in 0..255 by construction).
    rgb = np.stack([vertices[c] for c in ("red", "green", "blue")], 1)
    photos = [np.round(views.images[i].numpy() * 255).astype(np.uint8) for i in range(len(views))]
    np.testing.assert_array_equal(rgb, np.concatenate([p[k] for p, k in zip(photos, keeps, strict=True)]))

    for i, name in enumerate(views.names):
        depth = np.load(tmp_path / "geometry" / "depth" / f"{name}.npy")
        assert depth.dtype == np.float32
        np.testing.assert_array_equal(depth, rendered[i].depth)
        assert cv2.imread(str(tmp_path / "geometry" / "depth" / f"{name}.png")).shape == (views.height, views.width, 3)
    saved = json.loads((tmp_path / "geometry" / "export.json").read_text())
    assert [v["name"] for v in saved["views"]] == views.names
    assert [v["points"] for v in saved["views"]] == [int(k.sum()) for k in keeps]
    assert saved["scale"] == pytest.approx(scene.scale)


def test_export_geometry_verb_on_the_demo_config(tmp_path) -> None:
    from simplenerf.run.cli import make_cli
    from tests.run.test_cli import run, run_args

    args = run_args(tmp_path)
    cli = make_cli([*args, "--trainer.logger", "false"], run=False)  # an untrained model: its state dict will do
    ckpt = tmp_path / "model.ckpt"
    torch.save({"state_dict": cli.model.state_dict()}, ckpt)
    proc = run("export-geometry", "--config", "configs/demo.yaml", "--ckpt_path", str(ckpt), "--min_accumulation", "0",
               "--far_factor", "0", "--stride", "4", *args[2:], check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / "run" / "geometry"
    saved = json.loads((out / "export.json").read_text())
    height, width, n = saved["height"], saved["width"], len(saved["views"])
    # Every 4th pixel of each train view (no opacity or depth limit), all with finite positions.
    vertices = read_ply(out / "points.ply")
    assert len(vertices) == n * ((height + 3) // 4) * ((width + 3) // 4)
    assert np.isfinite(np.stack([vertices[a] for a in "xyz"], 1)).all()
    assert f"{out}/points.ply ({len(vertices)} points)" in proc.stdout
    assert sorted(p.name for p in (out / "depth").iterdir()) == sorted(
        f"{v['name']}.{ext}" for v in saved["views"] for ext in ("npy", "png"))
