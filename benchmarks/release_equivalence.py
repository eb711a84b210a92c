"""Is a training step here the authors' training step? Same weights, rays and random draws in; every output, loss
term, mask decision, gradient and updated weight compared with the release's (github NagabhushanSN95/SimpleNeRF at
c429746), plus the learning-rate schedule and a trajectory of many steps. Prints one markdown table (PASS / FAIL per
row) and exits non-zero if any row fails.

Needs a copy of the release (its `src/`), a Python with torch 2.13.0, this package and the release's few
dependencies, and the release's on-disk layout of the scene: `benchmarks/release_equivalence.sh` does all of that
(docs/equivalence.md). Directly:

    python benchmarks/release_equivalence.py --release-src $REL/src --run-root $REL/run_fern --scene fern \
        --scene-dir ../shared/data/nerf_llff_data/fern --views 2 --rays 256 --trajectory-steps 200

Settings of ours switched to the release's behaviour for the check (each listed in the table's notes):
`PatchReprojectionMask.require_in_front` false (the release has no z > 0 check), `rays_per_backward` null (the
release's two sub-batches: random rays, then sparse rays), `supervision: one_way` and `coarse_fine_on_sparse_rays`
(both our defaults already), sparse-depth weights 1 (the release's MSE is unweighted).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # `benchmarks.equivalence` from a checkout

import torch  # noqa: E402

from benchmarks.equivalence import release as rel  # noqa: E402
from benchmarks.equivalence import step as steps  # noqa: E402
from benchmarks.equivalence.report import Report, compare, flag  # noqa: E402
from benchmarks.equivalence.weights import copy_release_weights  # noqa: E402


def our_module(config: Path, scene_dir: Path, views: int):
    """Our SimpleNeRF from the paper config, with the release-faithful switches (module docstring)."""
    from simplenerf.cli import make_cli

    args = ["--config", str(config), "--data.init_args.scene_dir", str(scene_dir), "--data.init_args.n_views",
            str(views), "--model.rays_per_backward", "null", "--trainer.logger", "false"]
    module = make_cli(args, run=False).model
    for mask in [aug.mask for aug in module.augmentations] + [module.coarse_fine_mask]:
        if mask is not None and hasattr(mask, "require_in_front"):
            mask.require_in_front = False
    return module


def cast(batch: dict, dtype: torch.dtype) -> dict:
    """The release's batch with every floating tensor (also in `common_data`) in `dtype`."""
    def one(x):
        return x.to(dtype) if isinstance(x, torch.Tensor) and x.is_floating_point() else x
    return {k: cast(v, dtype) if isinstance(v, dict) else one(v) for k, v in batch.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--release-src", type=Path, required=True, help="the release's src/ folder (a copy at c429746)")
    ap.add_argument("--run-root", type=Path, required=True, help="the release's layout of the scene (build_layout.py)")
    ap.add_argument("--scene", default="fern", help="scene name in the layout")
    ap.add_argument("--scene-dir", type=Path, required=True, help="the LLFF scene folder (for our config)")
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--config", type=Path, default=REPO / "configs/llff.yaml")
    ap.add_argument("--rays", type=int, default=256, help="random rays = sparse-depth rays per step of the check")
    ap.add_argument("--iter", type=int, default=10000, help="the release's iteration of the checked step "
                    "(>= 10000: after the warm-up, every masked loss at weight 0.1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    ap.add_argument("--trajectory-steps", type=int, default=0, help="also run a trajectory of this many steps")
    ap.add_argument("--trajectory-rays", type=int, default=64)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here (markdown)")
    args = ap.parse_args()

    dtype = getattr(torch, args.dtype)
    # Tolerances (docs/equivalence.md explains them): elementwise rtol / atol for outputs and losses; the norm-wise
    # relative error of each gradient and of each parameter's Adam update. In float64 the release's inputs are still
    # float32-rounded (its cached rays and view directions), which bounds agreement at about 2.4e-7.
    rtol, atol, grad_rtol, update_rtol = ((1e-5, 1e-6, 1e-3, 1e-2) if dtype == torch.float32
                                          else (1e-6, 1e-8, 1e-6, 1e-4))
    rel.import_release(args.release_src)
    config = rel.published_config("llff")
    config["data_loader"].update(scene_names=[args.scene], train_set_num=args.views, num_rays=args.rays)
    config["data_loader"]["sparse_depth"]["num_rays"] = args.rays
    config["sub_batch_size"] = args.rays  # the published split: one sub-batch of random rays, one of sparse rays
    config["seed"] = args.seed
    started = time.perf_counter()
    run = rel.build_trainer(config, args.run_root)
    module = our_module(args.config, args.scene_dir, args.views)
    module.train()
    mapping = copy_release_weights(run.model, module)
    report = Report()
    group = f"{args.scene} {args.views}v {args.dtype}"

    # The learning-rate schedule: the release's decayer vs our ExponentialDecay.
    from simplenerf.optim import ExponentialDecay

    schedule = ExponentialDecay(torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=5e-4))
    for step in (0, 10_000, 100_000, 250_000):
        report.add(compare("learning rate", f"lr at step {step}", 5e-4 * schedule.factor(step),
                           run.lr_decayer.get_updated_learning_rate(step), rtol=1e-12, atol=0))

    # One step after the warm-up, from the same weights.
    batch = run.data.get_next_batch(args.iter)  # the release caches its rays in float32
    if dtype != torch.float32:  # both models and the batch in float64 (the release's loss sums stay float32)
        torch.set_default_dtype(dtype)
        run.model.to(dtype), module.to(dtype)
        batch = cast(batch, dtype)
    ours_batch = steps.to_training_batch(batch)
    module.train_views = steps.train_views(batch)
    for name in ("points", "views", "cfc"):
        module.loss_weights[name] = 0.1  # the release's iter_weights at iteration >= 10000
    generator = torch.Generator().manual_seed(args.seed)
    theirs, forwards = steps.run_release_step(run, copy.copy(batch), args.iter, generator)
    draws = steps.release_draws(run, forwards, ["coarse", "points", "views"])
    optimizer = steps.our_optimizer(module, args.iter)
    def value(v):
        return str(float(v)) if isinstance(v, int | float) and not isinstance(v, bool) else str(v)

    for key in ("lr", "betas", "eps", "weight_decay", "amsgrad"):
        ours_values = {value(g[key]) for g in optimizer.param_groups}
        release_values = {value(g[key]) for g in run.optimizer.param_groups}
        report.add(flag("optimiser", f"Adam {key} at iteration {args.iter}", ours_values == release_values,
                        f"ours {sorted(ours_values)}, release {sorted(release_values)}"))
    mine = steps.run_our_step(module, ours_batch, draws, optimizer)
    report.add(*steps.step_rows(group, theirs, mine, run.model, module, mapping, rtol, atol, grad_rtol,
                                update_rtol))
    report.add(flag("settings", "switched to the release's behaviour", True,
                    "PatchReprojectionMask.require_in_front=false; rays_per_backward=null; supervision one_way; "
                    "coarse_fine_on_sparse_rays true; sparse-depth weights 1"))

    if args.trajectory_steps:
        from benchmarks.equivalence.trajectory import run_trajectory

        run.data.num_rays = run.data.num_rays_sparse_depth = args.trajectory_rays
        run.config["sub_batch_size"] = args.trajectory_rays
        loss_rtol, weight_rtol = (1e-4, 1e-3) if dtype == torch.float32 else (1e-6, 1e-5)
        report.add(*run_trajectory(run, module, args.trajectory_steps, args.seed, group, loss_rtol, weight_rtol,
                                   log=lambda line: print(line, file=sys.stderr, flush=True)))

    print(report.markdown())
    print(f"\n{time.perf_counter() - started:.0f} s", file=sys.stderr)
    if args.out:
        args.out.write_text(report.markdown() + "\n")
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
