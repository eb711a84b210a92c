"""Tests of evaluation.rescore: a hand-made test folder on the synthetic scene scored again, and the tool end to end."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from simplenerf.data.llff import load_llff_scene
from simplenerf.errors import DataError
from simplenerf.evaluation.evaluator import ALL_METRICS
from simplenerf.evaluation.rescore import comparison_table, find_test_folder, read_rgb, rescore_run
from simplenerf.evaluation.visibility import scene_visibility_masks
from simplenerf.metrics.scores import PSNR_CAP, frame_scores
from simplenerf.viz.pictures import write_mask_png, write_png


@pytest.fixture
def tested(synthetic_scene, tmp_path):
    """A test folder of the 2-view synthetic scene: frame 000 predicted perfectly, 008 and 016 with noise; depth 1.1x
    the reference; saved masks: the left half of each frame; metrics.csv with made-up old scores (all 0.5)."""
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    folder = tmp_path / "run" / "test"
    for sub in ("rgb", "depth", "mask"):
        (folder / sub).mkdir(parents=True)
    generator = torch.Generator().manual_seed(0)
    for index in scene.split.test:
        name = scene.views.names[index]
        image = scene.views.images[index].double()
        if index:
            image = (image + 0.1 * torch.randn(image.shape, generator=generator, dtype=image.dtype)).clamp(0, 1)
        write_png(folder / "rgb" / f"{name}.png", image.numpy())
        np.save(folder / "depth" / f"{name}.npy", 1.1 * scene.views.depths[index].numpy())
        mask = np.zeros((scene.views.height, scene.views.width), dtype=bool)
        mask[:, : scene.views.width // 2] = True
        write_mask_png(folder / "mask" / f"{name}.png", mask)
    with open(folder / "metrics.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["frame", "index", *ALL_METRICS])
        writer.writeheader()
        for index in scene.split.test:
            writer.writerow({"frame": scene.views.names[index], "index": index, **dict.fromkeys(ALL_METRICS, 0.5)})
    return scene, folder


def test_rescore_scores_the_saved_frames_over_saved_and_new_masks(tested):
    scene, folder = tested
    results = rescore_run(folder, scene, None)
    assert list(results) == ["old", "saved_masks", "new"]
    assert results["old"] == dict.fromkeys(ALL_METRICS, 0.5)
    # Frame 000 is perfect: its full-frame PSNR is the cap; depth is 1.1x the reference everywhere, so the depth MAE
    # is 0.1 x mean(depth) / median(depth) per frame, and SROCC is 1.
    rows = list(csv.DictReader(open(folder / "rescored" / "saved_masks.csv")))
    assert [r["frame"] for r in rows] == ["000", "008", "016"] and float(rows[0]["psnr"]) == PSNR_CAP
    for row in rows:
        depth = scene.views.depths[int(row["index"])].double().numpy()
        assert float(row["depth_mae"]) == pytest.approx(0.1 * depth.mean() / np.median(depth), rel=1e-6)
        assert float(row["masked_depth_srocc"]) == pytest.approx(1.0)
        assert row["lpips"] == ""
    # Exactly what frame_scores gives on the saved PNG with the saved (left-half) mask and with the new masks.
    left = torch.zeros(scene.views.height, scene.views.width, dtype=torch.bool)
    left[:, : scene.views.width // 2] = True
    masks = scene_visibility_masks(scene.views, scene.split.train, scene.split.test, progress=False)
    for kind, mask_of in (("saved_masks", lambda i: left), ("new", masks.__getitem__)):
        expected = [frame_scores(read_rgb(folder / "rgb" / f"{scene.views.names[i]}.png"), scene.views.images[i],
                                 1.1 * scene.views.depths[i], scene.views.depths[i], None, mask_of(i))
                    for i in scene.split.test]
        for name in ALL_METRICS:
            values = [e[name] for e in expected if e[name] is not None]
            assert results[kind][name] == (pytest.approx(float(np.mean(values))) if values else None), (kind, name)
    summary = json.loads((folder / "rescored" / "new.json").read_text())
    assert summary["masks"] == "new" and summary["frames"] == 3 and summary["rescored_from"] == str(folder)
    saved = (folder / "rescored" / "mask" / "008.png")
    assert saved.is_file()
    assert results["new"]["masked_ssim"] != results["saved_masks"]["masked_ssim"]


def test_comparison_table_and_folder_errors(tested, tmp_path):
    _, folder = tested
    table = comparison_table({"old": dict.fromkeys(ALL_METRICS, 0.5), "new": {"psnr": 20.0}})
    assert table.splitlines()[:3] == ["| metric | old | new |", "|---|---:|---:|", "| psnr | 0.5000 | 20.0000 |"]
    assert table.splitlines()[3] == "| ssim | 0.5000 | - |"
    assert find_test_folder(folder.parent) == folder and find_test_folder(folder) == folder
    with pytest.raises(DataError, match="metrics.csv not found"):
        find_test_folder(tmp_path / "nothing")


def test_the_tool_rescores_a_cli_run(tmp_path):
    """`fit` 1 step and `test` through the CLI, then the tool: its new scores equal the test's own (same code)."""
    from tests.run.test_cli import run, run_args

    run("fit", *run_args(tmp_path), "--trainer.max_steps", "1", "--data.init_args.sparse_rays_per_batch", "0")
    run("test", *run_args(tmp_path), "--ckpt_path", "last", "--evaluation.lpips", "false")
    done = run("rescore", str(tmp_path / "run"), "--no_lpips", check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    old = json.loads((tmp_path / "run" / "test" / "summary.json").read_text())
    new = json.loads((tmp_path / "run" / "test" / "rescored" / "new.json").read_text())
    for name in ALL_METRICS:  # the same float32 sums in another order (threads, kernels): a few ulps apart
        expected = pytest.approx(old[name], rel=1e-6, abs=1e-6) if old[name] is not None else None
        assert new[name] == expected, name
    assert "| masked_ssim |" in done.stdout
