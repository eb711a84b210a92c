import csv
import json
import re
import shutil
import subprocess
import sys

import pytest

from simplenerf import commands
from simplenerf.commands.results import main
from simplenerf.errors import DataError
from simplenerf.reporting import paper_scores
from simplenerf.reporting.records import KEYS, RELEASE_MODEL, expand_runs, load_records, mean_rows
from tests.conftest import REPO, require_shared

# (model, scene, views) -> masked LPIPS, SSIM, PSNR, full-frame LPIPS, SSIM, PSNR, masked depth MAE, SROCC.
# Means over the two scenes are exact in binary, so the expected cells below are exact.
RUNS = {
    ("SimpleNeRF", "fern", 2): (0.25, 0.5, 20.0, 0.375, 0.375, 18.0, 0.125, 0.75),
    ("SimpleNeRF", "horns", 2): (0.5, 0.75, 21.0, 0.625, 0.5, 19.0, 0.25, 0.875),
    ("SimpleNeRF", "fern", 3): (0.125, 0.625, 22.0, 0.25, 0.5, 20.0, 0.0625, 0.875),
    ("SimpleNeRF", "horns", 3): (0.25, 0.875, 23.0, 0.5, 0.625, 21.0, 0.125, 0.9375),
    ("DS-NeRF", "fern", 2): (0.5, 0.25, 17.0, 0.75, 0.125, 15.0, 0.5, 0.5),
    ("DS-NeRF", "horns", 2): (0.75, 0.5, 18.5, 0.875, 0.25, 16.5, 0.75, 0.625),
    ("DS-NeRF", "fern", 3): (0.375, 0.5, 19.0, 0.5, 0.25, 17.0, 0.25, 0.625),
    ("DS-NeRF", "horns", 3): (0.625, 0.625, 20.0, 0.75, 0.375, 18.0, 0.5, 0.75),
}
FIELDS = ("masked_lpips", "masked_ssim", "masked_psnr", "lpips", "ssim", "psnr", "masked_depth_mae",
          "masked_depth_srocc")
HEADER_2_3_4 = [
    "|  | 2 views |  |  | 3 views |  |  | 4 views |  |  |",
    "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ |",
]


def write_run(folder, scene, n_views, values, frames=None, **extra):
    """A run folder with test/summary.json and test/metrics.csv in the shared format (no full-frame depth: no reference
    depth). Without `frames` (key -> one score per frame), its 3 frames all score `values`."""
    scores = {"depth_mae": None, "depth_srocc": None, **dict(zip(FIELDS, values or (), strict=values is not None)),
              **extra}
    frames = frames or {key: [value] * 3 for key, value in scores.items()}
    count = len(next(iter(frames.values())))
    summary = {"scene": scene, "n_views": n_views, "frames": count, **scores, "checkpoint": None, "git_commit": None,
               "config": None}
    (folder / "test").mkdir(parents=True)
    (folder / "test" / "summary.json").write_text(json.dumps(summary))
    with open(folder / "test" / "metrics.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["frame", "index", *KEYS])
        writer.writeheader()
        for i in range(count):
            writer.writerow({"frame": f"{8 * i:03d}", "index": 8 * i,
                             **{key: frames.get(key, [None] * count)[i] for key in KEYS}})
    return folder


@pytest.fixture
def runs(tmp_path):
    """runs/<model>/<scene>_<n>v for the 2 models x 2 scenes x 2 view counts of RUNS."""
    for (model, scene, n), values in RUNS.items():
        write_run(tmp_path / "runs" / model / f"{scene}_{n}v", scene, n, values)
    return tmp_path / "runs"


def args_for(runs):
    return [f"SimpleNeRF={runs}/SimpleNeRF/*", f"DS-NeRF={runs}/DS-NeRF/*"]


def table_lines(out):
    return [line for line in out.splitlines() if line.startswith("|")]


def test_table1_layout_means_and_missing_views(runs, capsys):
    main([*args_for(runs), "--views", "2", "3", "4"])
    out, err = capsys.readouterr()
    assert out.splitlines()[0].startswith("Masked scores (pixels seen by at least two train views)")
    assert table_lines(out) == [
        *HEADER_2_3_4,
        "| SimpleNeRF | 0.3750 | 0.6250 | 20.50 | 0.1875 | 0.7500 | 22.50 | - | - | - |",
        "| DS-NeRF | 0.6250 | 0.3750 | 17.75 | 0.5000 | 0.5625 | 19.50 | - | - | - |",
    ]
    assert err == ""  # both models cover the same scenes


def test_default_views_are_those_with_runs(runs, capsys):
    main(args_for(runs))
    lines = table_lines(capsys.readouterr().out)
    assert lines[0] == "|  | 2 views |  |  | 3 views |  |  |"
    assert lines[2] == "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ |"


def test_full_frame_and_both_scores(runs, capsys):
    main([*args_for(runs), "--scores", "full"])
    assert table_lines(capsys.readouterr().out)[3:] == [
        "| SimpleNeRF | 0.5000 | 0.4375 | 18.50 | 0.3750 | 0.5625 | 20.50 |",
        "| DS-NeRF | 0.8125 | 0.1875 | 15.75 | 0.6250 | 0.3125 | 17.50 |",
    ]
    main([*args_for(runs), "--scores", "both"])
    out = capsys.readouterr().out
    assert "full-frame scores in parentheses" in out.splitlines()[0]
    assert table_lines(out)[3] == ("| SimpleNeRF | 0.3750 (0.5000) | 0.6250 (0.4375) | 20.50 (18.50) | "
                                   "0.1875 (0.3750) | 0.7500 (0.5625) | 22.50 (20.50) |")


def test_depth_columns(runs, capsys):
    main([*args_for(runs), "--depth", "--views", "2"])
    lines = table_lines(capsys.readouterr().out)
    assert lines[0] == "|  | 2 views |  |  |  |  |"
    assert lines[2] == "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | MAE ↓ | SROCC ↑ |"
    assert lines[3] == "| SimpleNeRF | 0.3750 | 0.6250 | 20.50 | 0.1875 | 0.8125 |"
    main([*args_for(runs), "--depth", "--views", "2", "--scores", "full"])  # no reference depth: no full depth
    assert table_lines(capsys.readouterr().out)[3] == "| SimpleNeRF | 0.5000 | 0.4375 | 18.50 | - | - |"


def test_csv_long_format(runs, tmp_path, capsys):
    main([*args_for(runs), "--scores", "both", "--csv", str(tmp_path / "out" / "table.csv")])
    with open(tmp_path / "out" / "table.csv", newline="") as f:
        lines = list(csv.reader(f))
    assert lines[0] == ["table", "model", "source", "n_views", "metric", "value", "scenes", "frames", "std", "runs"]
    assert lines[1] == ["mean", "SimpleNeRF", "measured", "2", "masked_lpips", "0.375", "fern;horns", "6", "", ""]
    assert lines[2] == ["mean", "SimpleNeRF", "measured", "2", "lpips", "0.5", "fern;horns", "6", "", ""]
    assert ["mean", "DS-NeRF", "measured", "3", "psnr", "17.5", "fern;horns", "6", "", ""] in lines
    assert len(lines) == 1 + 2 * 2 * 6  # models x views x (3 metrics, masked and full)


def test_unequal_scene_sets_warn_and_name_the_missing_runs(runs, capsys):
    shutil.rmtree(runs / "DS-NeRF" / "horns_3v")
    main(args_for(runs))
    out, err = capsys.readouterr()
    assert err.splitlines() == [
        "warning: 3 views: models are averaged over different scenes; missing runs: (DS-NeRF, horns, 3 views)"]
    assert table_lines(out)[4] == "| DS-NeRF | 0.6250 | 0.3750 | 17.75 | 0.3750 | 0.5000 | 19.00 |"


def test_scene_without_masks_leaves_the_masked_mean_out(tmp_path, capsys):
    write_run(tmp_path / "a", "fern", 2, RUNS[("SimpleNeRF", "fern", 2)])
    no_masks = dict.fromkeys(("masked_lpips", "masked_ssim", "masked_psnr"))
    write_run(tmp_path / "b", "horns", 2, RUNS[("SimpleNeRF", "horns", 2)], **no_masks)
    main([f"SimpleNeRF={tmp_path}/a", f"SimpleNeRF={tmp_path}/b"])
    out, err = capsys.readouterr()
    assert table_lines(out)[3] == "| SimpleNeRF | - | - | - |"
    assert err == (f"warning: SimpleNeRF, 2 views: horns has no masked_lpips, masked_ssim, masked_psnr "
                   f"({tmp_path}/b/test/metrics.csv), so those means are left out\n")


def test_means_run_over_all_frames_not_over_scene_means(tmp_path, capsys):
    """fern: 1 frame of PSNR 20; horns: 3 frames of PSNR 22, 23, 27. The frame mean (20 + 22 + 23 + 27) / 4 = 23 is
    the table's (the paper's averaging); the mean of the scene means (20 + 24) / 2 = 22 is not. A frame without a
    score (horns' second frame has no masked SSIM: an empty mask) is left out of that score's mean only."""
    full = {key: [0.5] for key in FIELDS}
    write_run(tmp_path / "a", "fern", 2, None, frames={**full, "psnr": [20.0], "masked_ssim": [0.25]})
    three = {key: [0.5] * 3 for key in FIELDS}
    write_run(tmp_path / "b", "horns", 2, None, frames={**three, "psnr": [22.0, 23.0, 27.0],
                                                         "masked_ssim": [0.5, None, 0.75]})
    records = load_records(expand_runs([f"A={tmp_path}/a", f"A={tmp_path}/b"]))
    assert [r.scores["psnr"] for r in records] == [20.0, 24.0]  # scene means
    row = mean_rows(records)[0]
    assert row.values[(2, "psnr")] == 23.0 and row.frames[(2, "psnr")] == 4
    assert row.values[(2, "masked_ssim")] == 0.5 and row.frames[(2, "masked_ssim")] == 3  # (0.25 + 0.5 + 0.75) / 3
    main([f"A={tmp_path}/a", f"A={tmp_path}/b", "--scores", "full"])
    assert table_lines(capsys.readouterr().out)[3] == "| A | 0.5000 | 0.5000 | 23.00 |"
    main([f"A={tmp_path}/a", f"A={tmp_path}/b", "--scores", "full", "--per_scene"])
    out = capsys.readouterr().out
    assert table_lines(out.split("### horns")[1])[3] == "| A | 0.5000 | 0.5000 | 24.00 |"


def test_per_scene_tables(runs, capsys):
    main([*args_for(runs), "--per_scene", "--scores", "both"])
    out = capsys.readouterr().out
    assert [line for line in out.splitlines() if line.startswith("###")] == ["### fern", "### horns"]
    fern = out.split("### fern")[1].split("### horns")[0]
    assert table_lines(fern) == [
        "|  | 2 views |  |  | 3 views |  |  |",
        "|---|---:|---:|---:|---:|---:|---:|",
        "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | LPIPS ↓ | SSIM ↑ | PSNR ↑ |",
        "| SimpleNeRF | 0.2500 (0.3750) | 0.5000 (0.3750) | 20.00 (18.00) | 0.1250 (0.2500) | 0.6250 (0.5000) | "
        "22.00 (20.00) |",
        "| DS-NeRF | 0.5000 (0.7500) | 0.2500 (0.1250) | 17.00 (15.00) | 0.3750 (0.5000) | 0.5000 (0.2500) | "
        "19.00 (17.00) |",
    ]


def test_paper_rows_beside_the_measured_ones(runs, capsys):
    main([*args_for(runs), "--paper", "llff"])
    out, err = capsys.readouterr()
    lines = table_lines(out)
    assert lines[:3] == HEADER_2_3_4  # the paper has all three view counts
    assert [line.split(" | ")[0] for line in lines[3:]] == [
        "| RegNeRF (paper)", "| FreeNeRF (paper)", "| DS-NeRF (paper)", "| DDP-NeRF (paper)", "| ViP-NeRF (paper)",
        "| SimpleNeRF (paper)", "| SimpleNeRF", "| DS-NeRF"]
    assert lines[8] == ("| SimpleNeRF (paper) | 0.2688 | 0.6501 | 19.57 | 0.2559 | 0.6940 | 21.37 | 0.2633 | 0.7016 "
                        "| 21.99 |")
    assert lines[9] == "| SimpleNeRF | 0.3750 | 0.6250 | 20.50 | 0.1875 | 0.7500 | 22.50 | - | - | - |"
    assert err.splitlines()[0] == ("note: 2 views: the (paper) rows are means over 8 scenes (fern, flower, fortress, "
                                   "horns, leaves, orchids, room, trex), the measured rows over fern, horns")
    # Full-frame: only the SimpleNeRF numbers in paper_scores.FULL_FRAME; rows without any shown value are left out.
    main(["--paper", "llff", "--scores", "full", "--depth"])
    lines = table_lines(capsys.readouterr().out)
    assert lines[3:] == ["| SimpleNeRF (paper) | 0.390 | 0.553 | 17.57 | 0.278 | 0.753 |"]


def tex_rows(tex, label, block=0):
    """model -> numbers as printed, of the `block`-th group of rows (between two \\hline) of the tabular labelled
    `label`."""
    body = tex[:tex.index(f"\\label{{{label}}}")].rsplit("\\begin{tabular}", 1)[1]
    rows = {}
    for line in body.split("\\hline")[2 + block].strip().splitlines():
        cells = [re.sub(r"\\textbf\{(.*)\}", r"\1", c).strip() for c in line.strip().rstrip("\\ ").split("&")]
        rows[cells[0]] = tuple(cells[1:])
    return rows


def test_paper_scores_are_the_tex_numbers():
    tex = require_shared("paper/SimpleNeRF.tex").read_text()
    # Same models in the same order, same numbers.
    assert list(tex_rows(tex, "tab:quantitative-llff").items()) == list(paper_scores.LLFF_MAIN.items())
    assert list(tex_rows(tex, "tab:quantitative-realestate").items()) == list(paper_scores.REALESTATE_MAIN.items())
    depth = {m: (*llff, *re10k) for m, (llff, re10k) in paper_scores.DEPTH.items()}
    assert tex_rows(tex, "tab:quantitative-depth") == depth
    ablations = {m: (*re10k, *llff) for m, (re10k, llff) in paper_scores.ABLATIONS.items()}
    assert tex_rows(tex, "tab:quantitative-ablations") | tex_rows(tex, "tab:quantitative-ablations", 1) == ablations


def test_paper_table_lookups():
    llff = paper_scores.TABLES["llff"].rows
    assert llff["DDP-NeRF"][(3, "masked_psnr")] == "18.73"
    assert llff["ViP-NeRF"][(2, "masked_depth_srocc")] == "0.7344"
    assert paper_scores.TABLES["realestate"].rows["SimpleNeRF"][(2, "masked_depth_mae")] == "0.3269"
    assert paper_scores.TABLES["llff-ablations"].rows["w/o reliable depth"] == {
        (2, "masked_lpips"): "0.3020", (2, "masked_depth_mae"): "0.22"}


def test_errors_say_what_to_do(tmp_path, capsys):
    with pytest.raises(DataError, match=r"test/summary.json not found: test the run first with `python -m simplenerf "
                                        r"test"):
        load_records([("A", tmp_path)])
    write_run(tmp_path / "old", None, 2, RUNS[("SimpleNeRF", "fern", 2)])  # a summary without its scene
    with pytest.raises(DataError, match=r"old/test/summary.json: expected \"scene\".*found scene=None, n_views=2"):
        load_records([("A", tmp_path / "old")])
    with pytest.raises(DataError, match="expected NAME=RUN_DIR"):
        expand_runs(["runs/fern"])
    (tmp_path / "old" / "test" / "summary.json").write_text(json.dumps({"scene": "fern", "n_views": 2}))
    (tmp_path / "old" / "test" / "metrics.csv").unlink()
    with pytest.raises(DataError, match=r"old/test/metrics.csv not found: the table averages the frames"):
        load_records([("A", tmp_path / "old")])
    release = tmp_path / "test2011"
    (release / "QA_Scores" / "predicted_frames").mkdir(parents=True)
    csv_file = release / "QA_Scores" / "predicted_frames" / "PSNR02_FrameWise.csv"
    csv_file.write_text("scene_name,pred_frame_num,PSNR02\nfern,0,20.0\n")
    with pytest.raises(DataError, match=r"test2011: how many train views\? .* name it as .*test2011@N"):
        load_records(expand_runs([str(release)]))
    assert load_records(expand_runs([f"{release}@3"]))[0].n_views == 3
    with pytest.raises(DataError, match="no run folder matches"):
        expand_runs([f"A={tmp_path}/nothing_*"])
    write_run(tmp_path / "x", "fern", 2, RUNS[("SimpleNeRF", "fern", 2)])
    write_run(tmp_path / "y", "fern", 2, RUNS[("SimpleNeRF", "fern", 2)])
    write_run(tmp_path / "z", "horns", 2, RUNS[("SimpleNeRF", "horns", 2)])
    with pytest.raises(DataError, match="A with 2 views has 2 of fern, 1 of horns: give every scene the same number"):
        mean_rows(load_records(expand_runs([f"A={tmp_path}/x", f"A={tmp_path}/y", f"A={tmp_path}/z"])))
    with pytest.raises(SystemExit) as stop:
        commands.main(["results", f"A={tmp_path}/missing"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.startswith("simplenerf: error: ") and err.count("\n") == 1


def test_mean_rows_keep_the_given_model_order(runs):
    records = load_records(expand_runs([f"B={runs}/DS-NeRF/fern_2v", f"A={runs}/SimpleNeRF/*",
                                        f"B={runs}/DS-NeRF/horns_2v"]))
    rows = mean_rows(records)
    assert [row.model for row in rows] == ["B", "A"]
    assert rows[0].scenes == {2: ("fern", "horns")}
    assert rows[0].values[(2, "masked_psnr")] == 17.75


def test_the_tool_runs(runs):
    tool = [sys.executable, str(REPO / "tools" / "results.py")]
    done = subprocess.run([*tool, f"SimpleNeRF={runs}/SimpleNeRF/*"], capture_output=True, text=True, check=True)
    assert "| SimpleNeRF | 0.3750 | 0.6250 | 20.50 | 0.1875 | 0.7500 | 22.50 |" in done.stdout
    failed = subprocess.run([*tool, f"A={runs}/none"], capture_output=True, text=True)
    assert failed.returncode == 2 and failed.stderr.startswith("simplenerf: error: ")


def test_repeats_of_a_scene_are_mean_and_sample_std(tmp_path, capsys):
    """What tools/compare_runs.py's seed table gave: a NAME given for several runs of the same scene and views (seeds)
    is one row of mean ± sample standard deviation over them; a model with one run keeps plain cells."""
    a0 = write_run(tmp_path / "a0", "fern", 2, (0.25, 0.5, 20.0, 0.375, 0.375, 18.0, 0.125, 0.75))
    a1 = write_run(tmp_path / "a1", "fern", 2, (0.75, 0.5, 22.0, 0.375, 0.375, 18.0, 0.125, 0.75))
    b = write_run(tmp_path / "b", "fern", 2, RUNS[("DS-NeRF", "fern", 2)])
    main([f"A={a0}", f"A={a1}", f"B={b}", "--csv", str(tmp_path / "t.csv")])
    out = capsys.readouterr().out
    assert "Cells a ± b: mean ± sample standard deviation over a model's runs of the same scenes" in out
    assert table_lines(out)[3:] == ["| A (2 runs) | 0.5000 ± 0.3536 | 0.5000 ± 0.0000 | 21.00 ± 1.41 |",
                                    "| B | 0.5000 | 0.2500 | 17.00 |"]
    with open(tmp_path / "t.csv", newline="") as f:
        lines = list(csv.reader(f))
    assert lines[3] == ["mean", "A", "measured", "2", "masked_psnr", "21.0", "fern", "6", repr(2**0.5), "2"]
    assert lines[4] == ["mean", "B", "measured", "2", "masked_lpips", "0.5", "fern", "3", "", ""]


def test_repeats_over_scenes_pair_the_runs_in_order(tmp_path):
    """Repeat r is the r-th run of each scene: its value is the mean over its scenes' frames."""
    runs = [write_run(tmp_path / f"{scene}{seed}", scene, 2, (0.25, 0.5, psnr, 0.375, 0.375, 18.0, 0.125, 0.75))
            for scene, seed, psnr in (("fern", 0, 20.0), ("horns", 0, 22.0), ("fern", 1, 23.0), ("horns", 1, 25.0))]
    row = mean_rows(load_records([("A", run) for run in runs]))[0]
    assert row.values[(2, "masked_psnr")] == 22.5  # repeats 21 and 24
    assert row.spread[(2, "masked_psnr")] == pytest.approx(4.5**0.5)  # stdev(21, 24)
    assert row.runs == {2: 2} and row.scenes == {2: ("fern", "horns")} and row.frames[(2, "masked_psnr")] == 12


def test_heldout_depth_error_joins_the_depth_columns(tmp_path, capsys):
    """What tools/compare_runs.py showed for real scenes without reference depth: `<run>/heldout_depth.json` (from
    `simplenerf heldout-depth --out`) as columns with --depth, averaged over a model's runs."""
    for name, mean, median in (("a", 0.25, 0.125), ("b", 0.5, 0.25)):
        run = write_run(tmp_path / name, "fern", 2, RUNS[("SimpleNeRF", "fern", 2)])
        (run / "heldout_depth.json").write_text(json.dumps({"rel_error_mean": mean, "rel_error_median": median}))
    main([f"A={tmp_path}/a", f"A={tmp_path}/b", "--depth", "--scores", "full"])
    lines = table_lines(capsys.readouterr().out)
    assert lines[2] == ("| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ | MAE ↓ | SROCC ↑ | held-out err. ↓ | "
                        "held-out err. median ↓ |")
    assert lines[3] == ("| A (2 runs) | 0.3750 ± 0.0000 | 0.3750 ± 0.0000 | 18.00 ± 0.00 | - | - | 0.3750 ± 0.1768 | "
                        "0.1875 ± 0.0884 |")
    main([f"A={tmp_path}/a", "--scores", "full"])  # without --depth: no depth columns
    assert table_lines(capsys.readouterr().out)[2] == "| Model | LPIPS ↓ | SSIM ↑ | PSNR ↑ |"


def test_runs_without_masked_scores_point_to_full_frame_scores(tmp_path, capsys):
    write_run(tmp_path / "a", "fern", 2, None, psnr=20.0, ssim=0.5, lpips=0.25)
    main([f"A={tmp_path}/a"])
    assert capsys.readouterr().err == ("note: no run has masked scores (its scene has no reference depth); --scores "
                                       "full shows the full-frame ones\n")


# ---------------------------------------------------------------------------------------------------------------------
# The authors' per-frame scores (../shared/reference_scores).

RELEASE_FOLDERS = ("test1011", "test1021", "test1031", "test0011", "test0021", "test0031")


@pytest.mark.parametrize("folder", RELEASE_FOLDERS)
def test_the_release_frame_scores_average_to_its_published_table_values(folder):
    """Every value of every QA_Scores.json (8 image and 6 depth metrics, masked and full) is the mean of the per-frame
    CSV scores over ALL frames of all scenes, to the 4 decimals it is printed with."""
    path = require_shared(f"reference_scores/{folder}")
    published = json.loads((path / "QA_Scores.json").read_text())
    scores = paper_scores.read_release_folder(path)
    assert {s.metric for s in scores} == {m for group in published.values() for m in group}
    assert len(scores) == 14
    assert paper_scores.release_summary(scores) == published


def test_the_release_row_is_the_papers_row(capsys):
    """The tool on the authors' 2/3/4-view LLFF folders prints the paper's Table 1 SimpleNeRF row and its depth
    table's LLFF row, digit for digit; the full-frame 2-view row gives paper_scores.FULL_FRAME's numbers."""
    folders = [str(require_shared(f"reference_scores/{f}")) for f in ("test1011", "test1021", "test1031")]
    main([*folders, "--paper", "llff", "--depth"])
    out, err = capsys.readouterr()
    lines = table_lines(out)
    paper = lines[-2].replace("SimpleNeRF (paper)", RELEASE_MODEL).strip("| ").split(" | ")
    release = lines[-1].strip("| ").split(" | ")
    # Published cells exist for 2 views (5 metrics) and 3 / 4 views (3 metrics each); each equals the release's.
    shown = [(p, r) for p, r in zip(paper, release, strict=True) if p != "-"]
    assert len(shown) == 1 + 5 + 3 + 3 and all(p == r for p, r in shown), (paper, release)
    assert release[:6] == ["SimpleNeRF (release)", "0.2688", "0.6501", "19.57", "0.1420", "0.8480"]
    assert err == ""  # the release covers the paper's 8 scenes
    main([folders[0], "--scores", "full", "--depth"])
    assert table_lines(capsys.readouterr().out)[3] == ("| SimpleNeRF (release) | 0.3899 | 0.5529 | 17.57 | 0.2777 | "
                                                       "0.7531 |")
    # Per scene: the frame means of each scene; fern's full-frame PSNR is PER_SCENE's 17.01.
    main([folders[0], "--scores", "full", "--per_scene"])
    out = capsys.readouterr().out
    fern = out.split("### fern")[1].split("###")[0]
    assert table_lines(fern)[3] == "| SimpleNeRF (release) | 0.5089 | 0.4967 | 17.01 |"


def test_release_and_measured_rows_mix_and_names_are_optional(runs, tmp_path, capsys):
    release = tmp_path / "test1011"
    shutil.copytree(require_shared("reference_scores/test1011"), release)
    records = load_records(expand_runs([f"Ours={runs}/SimpleNeRF/fern_2v", str(release), f"Mine={release}@3"]))
    assert [(r.model, r.scene, r.n_views) for r in records][:3] == [
        ("Ours", "fern", 2), (RELEASE_MODEL, "fern", 2), (RELEASE_MODEL, "flower", 2)]
    assert records[-1].model == "Mine" and records[-1].n_views == 3 and len(records) == 1 + 8 + 8
    fern = records[1]
    assert fern.frames["psnr"] == (15.2098, 16.5488, 19.2608) and fern.path == release / "QA_Scores"
