"""Is a training step here the authors' training step? Same weights, rays and random draws in; every output, loss
term, mask decision, gradient and updated weight compared with the release's (github NagabhushanSN95/SimpleNeRF at
c429746), plus the learning-rate schedule and a trajectory of many steps. Prints one markdown table (PASS / FAIL per
row) and exits non-zero if any row fails.

It needs a copy of the release (its `src/`; its split CSVs under `data/` beside it, or `--release-git`) and a
Python with torch 2.13.0, this package and the release's few dependencies; it builds the release's on-disk layout of
the scene itself (`benchmarks/equivalence/layouts.py`) under `--work-dir`. docs/equivalence.md has the setup:

    python -m benchmarks.equivalence.check --release-src $REL/src --scene-dir ../shared/data/nerf_llff_data/fern \
        --realestate ../shared/data/realestate10k/000c3ab189999a83

checks the data of fern with 2, 3 and 4 views (and the RealEstate-10K clip), one training step per view count and a
200-step trajectory with 2 views. `--device cuda` (or `cuda:N`) runs both sides' training steps and trajectory on that
GPU (the release's model and batches, our module, the captured outputs); the data rows stay on the CPU (they compare
the data pipelines, which run before anything is moved to a GPU in training).

Settings of ours switched to the release's behaviour for the check (each listed in the table's notes):
`PatchReprojectionMask.require_in_front` false (the release has no z > 0 check), `rays_per_backward` 2048 (the
release's two sub-batches: random rays, then sparse rays), `supervision: one_way` and `coarse_fine_on_sparse_rays`
(both our defaults already), sparse-depth weights 1 (the release's MSE is unweighted).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import torch

from benchmarks.equivalence import release as rel
from benchmarks.equivalence import step as steps
from benchmarks.equivalence.report import Report, compare, flag
from benchmarks.equivalence.weights import copy_release_weights

REPO = Path(__file__).resolve().parents[2]


class DeviceError(ValueError):
    """A `--device` that this machine cannot give (usage error, exit status 2)."""


def check_device(spec: str) -> torch.device:
    """`--device`: "cpu", "cuda" or "cuda:N", checked against this machine (one line on error)."""
    try:
        device = torch.device(spec)
    except RuntimeError:
        raise DeviceError(f"--device {spec!r}: not a device name; expected cpu, cuda or cuda:N") from None
    if device.type == "cpu":
        return torch.device("cpu")
    if device.type != "cuda":
        raise DeviceError(f"--device {spec!r}: the check runs on cpu or cuda[:N], not {device.type}")
    if not torch.cuda.is_available():
        raise DeviceError(f"--device {spec!r}: no CUDA device (torch.cuda.is_available() is False for torch "
                          f"{torch.__version__}); use --device cpu")
    index = 0 if device.index is None else device.index
    if index >= torch.cuda.device_count():
        raise DeviceError(f"--device {spec!r}: this machine has {torch.cuda.device_count()} CUDA device(s), "
                          f"numbered from 0")
    return torch.device("cuda", index)


def our_module(config: Path, scene_dir: Path, views: int, factor: int, device: torch.device = torch.device("cpu")):
    """Our SimpleNeRF from the paper config, with the release-faithful switches (module docstring), on `device`."""
    from simplenerf.method.reliability import PatchReprojectionMask
    from simplenerf.run.cli import make_cli

    args = ["--config", str(config), "--data.init_args.scene_dir", str(scene_dir), "--data.init_args.n_views",
            str(views), "--data.init_args.factor", str(factor), "--model.rays_per_backward", "2048",
            "--trainer.logger", "false"]
    module = make_cli(args, run=False).model
    for mask in [aug.mask for aug in module.augmentations] + [module.coarse_fine_mask]:
        if isinstance(mask, PatchReprojectionMask):
            mask.require_in_front = False
    return module.to(device)


def llff_step_layout(repo, work_dir: Path, scene_dir: Path, factor: int, config: dict, seed: int) -> Path:
    """The release's layout of an LLFF scene for the step check, with synthetic sparse depth for every frame
    (random pixels, depths uniform in disparity within the frame's bounds, as ../shared/tools/official_timing's
    build_layout.py): the sparse-depth loss only needs targets; the data check compares real ones."""
    import numpy as np
    import pandas as pd

    from benchmarks.equivalence.layouts import build_llff_layout, write_sparse_depth_csvs

    root = work_dir / "release_layout"
    layout = build_llff_layout(repo, root, scene_dir, factor)
    config["data_loader"]["resolution_suffix"] = layout["suffix"]
    folder = (layout["db"] / "all/estimated_depths" / config["data_loader"]["sparse_depth"]["dirname"]
              / scene_dir.name / f"estimated_depths{layout['suffix']}")
    rng = np.random.default_rng(seed)
    tables = {}
    for frame, (near, far) in enumerate(layout["bounds"]):
        n = 2000
        depth = 1.0 / rng.uniform(1.0 / far, 1.0 / near, n)
        x, y = rng.integers(0, layout["width"], n), rng.integers(0, layout["height"], n)
        tables[frame] = pd.DataFrame({"x": x, "y": y, "depth": depth, "reprojection_error": rng.uniform(0.05, 2.0, n),
                                      "weight": np.ones(n)})
    write_sparse_depth_csvs(folder, tables)
    return root


def step_check(args, repo, report: Report, views: int, trajectory: bool) -> None:
    """One training step (and optionally a trajectory) of the release and ours on `args.scene_dir` with `views`."""
    from benchmarks.equivalence.release import release_config

    dtype = getattr(torch, args.dtype)
    # Tolerances (docs/equivalence.md explains them): elementwise rtol / atol for outputs and losses; the norm-wise
    # relative error of each gradient and of each parameter's Adam update. In float64 the release's inputs are still
    # float32-rounded (its cached rays and view directions), which bounds agreement at about 2.4e-7.
    rtol, atol, grad_rtol, update_rtol = ((1e-5, 1e-6, 1e-3, 1e-2) if dtype == torch.float32
                                          else (1e-6, 1e-8, 1e-6, 1e-4))
    torch.set_default_dtype(torch.float32)
    config = release_config(repo, "llff", views)
    scene = args.scene_dir.name
    config["data_loader"].update(scene_names=[scene], num_rays=args.rays)
    config["data_loader"]["sparse_depth"]["num_rays"] = args.rays
    config["sub_batch_size"] = args.rays  # the published split: one sub-batch of random rays, one of sparse rays
    config["seed"] = args.seed
    run_root = llff_step_layout(repo, args.work_dir, args.scene_dir, args.factor, config, args.seed)
    run = rel.build_trainer(config, run_root, device=args.device)
    module = our_module(args.config, args.scene_dir, views, args.factor, args.device)
    module.train()
    mapping = copy_release_weights(run.model, module)
    group = f"step {scene} {views}v {args.dtype}" + ("" if args.device.type == "cpu" else f" {args.device}")

    if dtype != torch.float32:  # both models and the batch in float64 (the release's loss sums stay float32)
        torch.set_default_dtype(dtype)
        run.model.to(dtype), module.to(dtype)
    batch = steps.release_batch(run, args.iter)
    ours_batch = steps.to_training_batch(batch)
    module.set_train_views(steps.train_views(batch))
    for name in ("points", "views", "cfc"):
        module.terms[name].weight = 0.1  # the release's iter_weights at iteration >= 10000
    generator = torch.Generator().manual_seed(args.seed)
    theirs, forwards = steps.run_release_step(run, copy.copy(batch), args.iter, generator)
    draws = steps.release_draws(run, forwards, ["coarse", "points", "views"])
    optimizer = steps.our_optimizer(module, args.iter)

    def value(v):
        return str(float(v)) if isinstance(v, int | float) and not isinstance(v, bool) else str(v)

    for key in ("lr", "betas", "eps", "weight_decay", "amsgrad"):
        ours_values = {value(g[key]) for g in optimizer.param_groups}
        release_values = {value(g[key]) for g in run.optimizer.param_groups}
        report.add(flag(f"{group} optimiser", f"Adam {key} at iteration {args.iter}", ours_values == release_values,
                        f"ours {sorted(ours_values)}, release {sorted(release_values)}"))
    mine = steps.run_our_step(module, ours_batch, draws, optimizer)
    report.add(*steps.step_rows(group, theirs, mine, run.model, module, mapping, rtol, atol, grad_rtol,
                                update_rtol))
    if trajectory:
        from benchmarks.equivalence.trajectory import run_trajectory

        run.data.num_rays = run.data.num_rays_sparse_depth = args.trajectory_rays
        run.config["sub_batch_size"] = args.trajectory_rays
        loss_rtol, weight_rtol = (1e-4, 1e-2) if dtype == torch.float32 else (1e-6, 1e-4)
        report.add(*run_trajectory(run, module, args.trajectory_steps, args.seed, group, loss_rtol, weight_rtol,
                                   log=lambda line: print(line, file=sys.stderr, flush=True)))
    torch.set_default_dtype(torch.float32)


def device_name(device: torch.device) -> str:
    return "the CPU" if device.type == "cpu" else f"{device} ({torch.cuda.get_device_name(device)})"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--release-src", type=Path, required=True, help="the release's src/ folder (a copy at c429746)")
    ap.add_argument("--release-git", type=Path, default=None,
                    help="the release's git directory, to read its data/ (split CSVs) where --release-src's parent "
                         "has none (an extract of src/ only)")
    ap.add_argument("--work-dir", type=Path, default=Path("/tmp/simplenerf_release_equivalence"),
                    help="scratch folder outside the repository (the release's layouts and run folders)")
    ap.add_argument("--scene-dir", type=Path, default=REPO.parent / "shared/data/nerf_llff_data/fern",
                    help="an LLFF scene folder (poses_bounds.npy, images_<factor>/)")
    ap.add_argument("--factor", type=int, default=4, help="images_<factor> (4: the paper's 1008x756 for LLFF)")
    ap.add_argument("--views", type=int, nargs="+", default=[2, 3, 4], help="view counts checked")
    ap.add_argument("--realestate", type=Path, default=None,
                    help="also check the data pipeline on this RealEstate-10K clip folder (2 views)")
    ap.add_argument("--config", type=Path, default=REPO / "configs/llff.yaml")
    ap.add_argument("--rays", type=int, default=256, help="random rays = sparse-depth rays of the checked step")
    ap.add_argument("--iter", type=int, default=10000, help="the release's iteration of the checked step "
                    "(>= 10000: after the warm-up, every masked loss at weight 0.1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    ap.add_argument("--device", default="cpu", help="where both sides' training steps run: cpu (default), cuda or "
                    "cuda:N (the data rows stay on the CPU)")
    ap.add_argument("--trajectory-steps", type=int, default=200, help="steps of the trajectory (0: none), run "
                    "for the first view count")
    ap.add_argument("--trajectory-rays", type=int, default=16)
    ap.add_argument("--skip-data", action="store_true", help="only the training-step checks")
    ap.add_argument("--out", type=Path, default=None, help="also write the table here (markdown)")
    ap.add_argument("--json", type=Path, default=None, help="also write one JSON line here: device, rows, failed "
                    "rows, seconds (benchmarks/speed/gpu.sh collects it)")
    args = ap.parse_args(argv)
    try:
        args.device = check_device(args.device)
    except DeviceError as e:
        print(f"release_equivalence: {e}", file=sys.stderr)
        return 2
    args.work_dir = args.work_dir.resolve()
    args.scene_dir = args.scene_dir.resolve()

    from benchmarks.equivalence.data import NOTES, data_rows
    from benchmarks.equivalence.layouts import ReleaseRepo

    rel.import_release(args.release_src)
    repo = ReleaseRepo(args.release_src.resolve(), args.release_git)
    report = Report()
    started = time.perf_counter()

    # The learning-rate schedule: the release's decayer vs our ExponentialDecay.
    import lr_decayers.NeRFLearningRateDecayer01 as decayer

    from simplenerf.method.optim import ExponentialDecay

    theirs = decayer.NeRFLearningRateDecayer({"optimizer": {"lr_initial": 5e-4, "lr_decay": 250}})
    schedule = ExponentialDecay(torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=5e-4))
    for step in (0, 10_000, 100_000, 250_000):
        report.add(compare("learning rate", f"lr at step {step}", 5e-4 * schedule.factor(step),
                           theirs.get_updated_learning_rate(step), rtol=1e-12, atol=0))

    if not args.skip_data:
        cases = [("llff", args.scene_dir, n, args.factor) for n in args.views]
        if args.realestate:
            cases.append(("realestate", args.realestate.resolve(), 2, 1))
        for kind, scene_dir, n, factor in cases:
            t0 = time.perf_counter()
            report.add(*data_rows(args.release_src.resolve(), args.work_dir, scene_dir, kind, n, factor,
                                  release_git=args.release_git, seed=args.seed))
            print(f"data {scene_dir.name} {n}v: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    for i, n in enumerate(args.views):
        t0 = time.perf_counter()
        step_check(args, repo, report, n, trajectory=i == 0 and args.trajectory_steps > 0)
        print(f"step {args.scene_dir.name} {n}v: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    report.add(flag("settings", "switched to the release's behaviour", True,
                    "PatchReprojectionMask.require_in_front=false; rays_per_backward=2048; supervision one_way; "
                    "coarse_fine_on_sparse_rays true; sparse-depth weights 1; our rays = the release's rays"))

    table = report.markdown()
    print(table)
    print(f"\n{time.perf_counter() - started:.0f} s on {device_name(args.device)}; release {args.release_src}; "
          f"scene {args.scene_dir}\n")
    if not args.skip_data:
        print(NOTES)
    if args.out:
        args.out.write_text(table + "\n")
    if args.json:
        record = {"check": "release_equivalence", "device": str(args.device), "device_name": device_name(args.device),
                  "dtype": args.dtype, "views": args.views, "rays": args.rays,
                  "trajectory_steps": args.trajectory_steps, "data_rows": not args.skip_data,
                  "rows": len(report.rows), "passed_rows": sum(r.passed for r in report.rows),
                  "failed": [f"{r.group}: {r.quantity}" for r in report.rows if not r.passed],
                  "seconds": round(time.perf_counter() - started, 1), "torch": torch.__version__,
                  "release_src": str(args.release_src), "scene": str(args.scene_dir)}
        args.json.write_text(json.dumps(record) + "\n")
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
