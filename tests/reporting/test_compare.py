import json

import pytest

from simplenerf.reporting.compare import load_summaries, markdown_table, seed_table


def test_table_of_two_runs(tmp_path):
    for name, psnr in (("a", 20.0), ("b", 21.5)):
        (tmp_path / name / "test").mkdir(parents=True)
        summary = {"frames": 3, "psnr": psnr, "ssim": 0.5, "lpips": 0.3, "depth_mae": None, "depth_srocc": None}
        (tmp_path / name / "test" / "summary.json").write_text(json.dumps(summary))
    table = markdown_table(load_summaries({"A": tmp_path / "a", "B": tmp_path / "b" / "test"}))
    assert table.splitlines() == [
        "| run | psnr ↑ | ssim ↑ | lpips ↓ |",
        "|---|---:|---:|---:|",
        "| A | 20.0000 | 0.5000 | 0.3000 |",
        "| B | 21.5000 | 0.5000 | 0.3000 |",
    ]


def test_missing_run_says_what_to_do(tmp_path):
    with pytest.raises(FileNotFoundError, match="run `python -m simplenerf test"):
        load_summaries({"A": tmp_path})


def test_heldout_depth_error_joins_the_table(tmp_path):
    (tmp_path / "a" / "test").mkdir(parents=True)
    summary = {"frames": 3, "psnr": 20.0, "ssim": 0.5, "lpips": 0.3, "depth_mae": None, "depth_srocc": None}
    (tmp_path / "a" / "test" / "summary.json").write_text(json.dumps(summary))
    (tmp_path / "a" / "heldout_depth.json").write_text(json.dumps({"rel_error_mean": 0.25, "rel_error_median": 0.125}))
    table = markdown_table(load_summaries({"A": tmp_path / "a"}))
    header = "| run | psnr ↑ | ssim ↑ | lpips ↓ | heldout_rel_error_mean ↓ | heldout_rel_error_median ↓ |"
    assert table.splitlines()[0] == header
    assert table.splitlines()[2] == "| A | 20.0000 | 0.5000 | 0.3000 | 0.2500 | 0.1250 |"


def test_seed_table_gives_mean_and_sample_std(tmp_path):
    def summary(psnr, lpips):
        return {"frames": 3, "psnr": psnr, "ssim": None, "lpips": lpips, "depth_mae": None, "depth_srocc": None}

    groups = {"A": [summary(20.0, 0.3), summary(22.0, 0.5)], "B": [summary(21.0, 0.25)]}
    assert seed_table(groups).splitlines() == [
        "| model | runs | psnr ↑ | lpips ↓ |",
        "|---|---:|---:|---:|",
        "| A | 2 | 21.0000 ± 1.4142 | 0.4000 ± 0.1414 |",
        "| B | 1 | 21.0000 ± 0.0000 | 0.2500 ± 0.0000 |",
    ]
