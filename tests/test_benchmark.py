"""Speed measurement (benchmarks.speed.training_step, `simplenerf benchmark`, benchmarks/speed/): the counting
formulas by hand, frame cropping, the side-by-side table, and one short run of each measurement through the real
CLI."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

import pytest
import torch
from torch import nn

from benchmarks.speed import gpu_report, grid_sample_threads
from benchmarks.speed.profile_step import main as profile_main
from benchmarks.speed.profile_step import matmul_time
from benchmarks.speed.render import crop_rows
from benchmarks.speed.render import main as render_main
from benchmarks.speed.summarize import side_by_side_table
from benchmarks.speed.training_step import field_evaluations_per_ray, linear_macs, matmul_flop_per_ray
from simplenerf.commands.benchmark import main as benchmark_main
from simplenerf.commands.benchmark import training_args
from simplenerf.errors import CheckpointError
from simplenerf.run import hardware
from tests.run.test_cli import run_args


class _Aug(nn.Module):
    def __init__(self, stage: str, width: int = 4) -> None:
        super().__init__()
        self.stage, self.field = stage, nn.Linear(3, width)


class _Nerf(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.num_coarse, self.num_fine = 64, 128
        self.coarse, self.fine = nn.Sequential(nn.Linear(3, 5), nn.ReLU(), nn.Linear(5, 2)), nn.Linear(3, 7)


class _Model(nn.Module):
    def __init__(self, stages: list[str]) -> None:
        super().__init__()
        self.nerf, self.augmentations = _Nerf(), nn.ModuleList(_Aug(s) for s in stages)


def test_field_evaluations_per_ray_follows_the_formula():
    # coarse x (1 + coarse augmentations) + (coarse + fine) x (1 + fine augmentations)
    assert field_evaluations_per_ray(_Model(["coarse", "coarse"])) == 64 * 3 + 192  # the paper's 384
    assert field_evaluations_per_ray(_Model([])) == 64 + 192
    assert field_evaluations_per_ray(_Model(["coarse", "fine"])) == 64 * 2 + 192 * 2
    assert field_evaluations_per_ray(_Model(["coarse", "coarse"]), training=False) == 256


def test_matmul_flop_counts_linear_layers_per_sample():
    model = _Model(["coarse"])
    assert linear_macs(model.nerf.coarse) == 3 * 5 + 5 * 2
    forward = 2 * (64 * 25 + 192 * 21)
    assert matmul_flop_per_ray(model, training=False) == forward
    assert matmul_flop_per_ray(model) == 3 * (forward + 2 * 64 * 12)


@dataclass
class _Frame:
    origins: torch.Tensor
    height: int
    width: int
    index: int


def test_crop_rows_keeps_the_top_rows_of_dicts_and_dataclasses():
    pixels = torch.arange(4 * 3 * 2).reshape(12, 2)
    item = {"origins": pixels, "rgb": pixels + 1, "height": 4, "width": 3, "name": "x", "pose": torch.eye(4)}
    cut = crop_rows(item, 2)
    assert cut["height"] == 2 and cut["width"] == 3 and cut["name"] == "x"
    assert torch.equal(cut["origins"], pixels[:6]) and torch.equal(cut["rgb"], pixels[:6] + 1)
    assert torch.equal(cut["pose"], torch.eye(4))  # not a per-pixel tensor
    frame = crop_rows(_Frame(pixels, 4, 3, 0), 1)
    assert frame.height == 1 and torch.equal(frame.origins, pixels[:3])
    with pytest.raises(TypeError, match="no height"):
        crop_rows({"origins": pixels}, 1)


def test_side_by_side_table_pools_runs_and_leaves_out_short_batches(tmp_path):
    records = [{"seconds": s, "rays_rgb": 256, "rays_sd": sd, "user_s": s / 2, "sys_s": 0.5}
               for s, sd in ((9.0, 256), (4.0, 256), (6.0, 256), (1.0, 100))]
    release = {"variant": "B", "rays_rgb": 256, "rays_sd": 256, "discarded": 1, "peak_rss_mib": 4096,
               "records": records}
    (tmp_path / "release.json").write_text(json.dumps(release, indent=2))
    ours = [{"benchmark": "train_step", "label": "B", "precision": "32-true", "tf32": False, "rays_random": 256,
             "rays_sparse": 256, "s_per_it_all": all_s, "cpu_s_all": all_s, "peak_rss_gib": rss,
             "cpu": "AMD EPYC 7B13", "cpu_capability": "AVX2", "gpu": None}
            for all_s, rss in (([2.0], 1.5), ([2.5], 1.7))]
    (tmp_path / "ours.json").write_text("\n".join(json.dumps(r) for r in ours) + "\n")
    table = side_by_side_table([tmp_path / "release.json", tmp_path / "ours.json"])
    assert table.splitlines()[:2] == ["Machine: AMD EPYC 7B13 (AVX2)", ""]
    row = table.splitlines()[4]
    # release: iterations 2 and 3 (the first is discarded, the short batch left out) -> median 5.0; ours 2.25
    assert row.startswith("| B | 256+256 | 32-true | 5.00 (4.00-6.00, n=2) | 2.25 (2.00-2.50, n=2) | 2.22 |")
    assert "| 3.00 / 2.25 |" in row  # CPU seconds: release (2.0 + 0.5, 3.0 + 0.5), ours (2.0, 2.5)
    assert row.endswith("| 4.00 | 1.50-1.70 |")
    # a record of another CPU in the same table: refused, no ratio mixes machines
    other = {**ours[0], "cpu": "Intel(R) Xeon(R) Processor", "cpu_capability": "AVX-512"}
    (tmp_path / "other.json").write_text(json.dumps(other) + "\n")
    with pytest.raises(ValueError, match=r"different machines \(AMD EPYC 7B13 \(AVX2\); Intel\(R\) Xeon\(R\) "
                                         r"Processor \(AVX-512\)\): one sitting at a time"):
        side_by_side_table([tmp_path / "release.json", tmp_path / "ours.json", tmp_path / "other.json"])


def _tiny(tmp_path) -> list[str]:
    """The end-to-end tests' tiny demo run, as a benchmark's arguments: its configs, then `--` and its overrides."""
    args = run_args(tmp_path)
    configs = [a for i, a in enumerate(args) if a == "--config" or (i and args[i - 1] == "--config")]
    overrides = [a for i, a in enumerate(args) if not (a == "--config" or (i and args[i - 1] == "--config"))]
    return [*configs, "--", *overrides]


def test_train_step_and_render_run_through_the_cli(tmp_path, capsys):
    record = benchmark_main(["--steps", "2", "--warmup", "1", "--label", "tiny", "--rays", "48", *_tiny(tmp_path)])
    printed = capsys.readouterr()
    line = json.loads(printed.out.strip().splitlines()[-1])
    assert line == json.loads(json.dumps(record))
    assert line["label"] == "tiny" and len(line["s_per_it_all"]) == 2 and len(line["warmup_s"]) == 1
    assert line["rays_random"] == 48  # --rays, after the config's overrides (64)
    assert line["rays_per_it"] == line["rays_random"] + line["rays_sparse"] > 0
    assert line["field_evaluations_per_it"] == line["field_evaluations_per_ray"] * line["rays_per_it"]
    assert line["rays_per_s"] == pytest.approx(line["rays_per_it"] / line["s_per_it"])
    # no warm-up schedule: the masked depth losses are computed from the first step
    assert {"color", "sparse_depth", "points", "views", "cfc"} <= set(line["losses"])
    assert line["peak_rss_gib"] > 0 and line["peak_cuda_gib"] is None
    cpu = hardware.cpu()  # the machine, named in the JSON and on stderr before the first step
    assert (line["cpu"], line["cpu_capability"], line["torch_cpu_capability"]) == (cpu.model, cpu.capability,
                                                                                   torch.backends.cpu.get_cpu_capability())
    assert line["gpu"] == (torch.cuda.get_device_name() if torch.cuda.is_available() else None)
    assert f"simplenerf: {cpu.line()}; precision 32-true\n" in printed.err

    # benchmarks/speed/gpu.sh's figures: the measurement's JSON line, found in a step's log and summarised
    log = tmp_path / "benchmark_fp32.log"
    log.write_text(f"progress on stderr\n{json.dumps(record)}\nmore stderr\n")
    recorded = gpu_report.record(tmp_path / "gpu", "benchmark_fp32", "0", 12.34, from_json=log)
    assert recorded == {"step": "benchmark_fp32", "status": 0, "wall_s": 12.3, "measured": line}
    row = gpu_report.summary(tmp_path / "gpu").splitlines()[-1]
    assert row == (f"| benchmark_fp32 | done | 12 | {line['s_per_it']:.3f} ({line['s_per_it_min']:.3f}-"
                   f"{line['s_per_it_max']:.3f}) |  | {line['rays_per_s']:.0f} rays/s |")  # no CUDA: no GPU peak

    record = render_main(["--frames", "1", "--rows", "5", *_tiny(tmp_path)])
    assert record["frame_shape"][0] == 5 and record["rays_per_frame"] == 5 * record["frame_shape"][1]
    assert record["rays_per_s"] == pytest.approx(record["rays_per_frame"] / record["s_per_frame"])

    record = profile_main(["--warmup", "1", *_tiny(tmp_path)])
    # the warm-up iteration's matrix products, counted: at least the forward of the random rays' fields (colour
    # included), at most forward + backward of every ray with colour (the sparse rays skip their colour branches)
    model = training_args(["--warmup", "1", *_tiny(tmp_path)], "", {})[2].model
    flop = record["matmul_gflop"] * 1e9
    assert matmul_flop_per_ray(model, training=False) * 64 <= flop < matmul_flop_per_ray(model) * (64 + 32)
    assert record["matmul_s"] > 0 and record["other_ops_s"] > 0
    assert record["matmul_s"] + record["other_ops_s"] == pytest.approx(record["profiled_self_cpu_s"], rel=1e-6)
    assert "matrix products (aten::mm/addmm/bmm)" in capsys.readouterr().out


def test_matmul_time_separates_the_matrix_products():
    events = [("aten::mm", 2.0), ("aten::addmm", 1.0), ("aten::relu", 0.5), ("aten::copy_", 0.25)]
    assert matmul_time(events, 450 * 10**9) == {"matmul_s": 3.0, "matmul_gflop": 450.0, "matmul_gflop_per_s": 150.0,
                                                "other_ops_s": 0.75}
    assert matmul_time([("aten::relu", 0.5)], 0)["matmul_gflop_per_s"] == 0.0


def test_weights_load_a_checkpoint_of_the_config_and_name_one_that_does_not_fit(tmp_path):
    model = training_args(_tiny(tmp_path), "", {})[2].model
    trained = {name: torch.full_like(value, 0.25) if value.is_floating_point() else value
               for name, value in model.state_dict().items()}
    torch.save({"state_dict": trained, "global_step": 7}, tmp_path / "late.ckpt")
    loaded = training_args(["--weights", str(tmp_path / "late.ckpt"), *_tiny(tmp_path)], "", {})[2].model
    for name, value in loaded.state_dict().items():
        assert torch.equal(value, trained[name]), name  # the checkpoint's values, not a fresh initialisation

    name = next(n for n, v in trained.items() if v.is_floating_point() and v.dim() == 2)
    torch.save({"state_dict": {**trained, name: trained[name][:1]}}, tmp_path / "other.ckpt")
    other = re.escape(f"checkpoint {tmp_path / 'other.ckpt'} does not fit the model: {name} is ")
    with pytest.raises(CheckpointError, match=other):
        training_args(["--weights", str(tmp_path / "other.ckpt"), *_tiny(tmp_path)], "", {})


def test_grid_sample_threads_times_both_ways_and_names_what_sample_plane_picks(capsys, two_threads):
    record = grid_sample_threads.main(["--points", "200", "--samples", "10", "--planes", "2x4x8", "2x32x32",
                                       "--reps", "1"])
    assert [row["picks"] for row in record["rows"]] == [2, 1]  # 32 nodes <= 200 points; 1024 nodes > 200
    assert all(len(row["one_entry_ms"]) == 2 and len(row["per_thread_ms"]) == 2 for row in record["rows"])
    out = capsys.readouterr().out
    assert "| 2x4x8 |" in out and "one per thread |" in out and json.loads(out.splitlines()[-1]) == record


def test_grid_sample_threads_rays_run_along_the_height_axis_inside_the_box():
    coords = grid_sample_threads.ray_coords(25, 10, "ray", torch.Generator().manual_seed(0))  # 3 rays, the last cut
    assert coords.shape == (25, 2) and coords.abs().max() <= 1.0
    rays = coords[:20].view(2, 10, 2)
    assert torch.equal(rays[:, :, 0], rays[:, :1, 0].expand(2, 10))  # the width coordinate is the ray's own
    torch.testing.assert_close(rays[:, -1, 1] - rays[:, 0, 1], torch.full((2,), 0.1))
