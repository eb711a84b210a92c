"""Many training steps on both sides from the same initial weights, with the same ray batches and random draws.

Each iteration the release's data preprocessor draws the batch (`get_next_batch`, its own shuffled ray order) and the
release's `train_one_iter` trains on it; ours trains on the same rays (`step.to_training_batch`) with the release's
random draws of that iteration, with our configured optimiser and learning-rate schedule. The masked losses are on
from iteration 0 on both sides (the release's `iter_weights` set to {0: 0.1}, our weights to 0.1), so every term
is exercised in a short run. Per-iteration losses and the final weights are compared.
"""

from __future__ import annotations

import copy

import torch

from benchmarks.equivalence import step as steps
from benchmarks.equivalence.report import Row, compare
from benchmarks.equivalence.weights import copy_release_weights, release_to_ours

FLOAT32_ULP = 2.0**-23  # the relative spacing of float32 numbers in [1, 2)


def ulp_perturbed(module):
    """A copy of `module` whose every weight w is moved to w (1 +- 2^-23) (random sign, seeded): one float32 unit in
    the last place, in float64 too, where the release's float32-rounded inputs differ from ours by that much."""
    twin = copy.deepcopy(module)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in twin.parameters():
            # drawn on the CPU: the same signs on any device
            sign = torch.randint(0, 2, p.shape, generator=g).to(device=p.device, dtype=p.dtype) * 2 - 1
            p.mul_(1 + sign * FLOAT32_ULP)
    return twin


def run_trajectory(run, module, num_steps: int, seed: int, group: str, loss_rtol: float, weight_rtol: float,
                   log=print) -> list[Row]:
    """The trajectory's rows. Besides ours vs the release, ours is run a second time from weights one float32 ulp
    away (`ulp_perturbed`), on the same rays and draws: how far our own trajectory moves under rounding-sized changes
    is the floor below which no comparison of two implementations can go (training is chaotic in the weights: ReLU
    gates, mask decisions and Adam's first steps amplify them). A row passes when its error is within `loss_rtol` /
    `weight_rtol`, or within 3x that floor (the note says which)."""
    for name in steps.MASK_LOSSES.values():
        if name in run.loss_computer.losses:
            run.loss_computer.losses[name].loss_configs["iter_weights"] = {"0": 0.1}
    for name in ("points", "views", "cfc"):
        module.terms[name].weight = 0.1
    mapping = copy_release_weights(run.model, module)
    twin = ulp_perturbed(module)
    twin_optimizer = twin.configure_optimizers()
    inputs = []
    run.optimizer = run.trainer.optimizer = torch.optim.Adam(
        list(run.model.parameters()), lr=run.config["optimizer"]["lr_initial"],
        betas=(run.config["optimizer"]["beta1"], run.config["optimizer"]["beta2"]))
    configured = module.configure_optimizers()
    optimizer, schedule = configured["optimizer"], configured["lr_scheduler"]["scheduler"]
    generator = torch.Generator().manual_seed(seed)
    ours_losses, release_losses = [], []
    flips: dict[str, list[int]] = {}  # masked loss -> per step, rays whose mask decision differs
    for it in range(num_steps):
        batch = steps.release_batch(run, it)
        if not bool(batch["indices_mask_sparse_depth"].any()):
            raise RuntimeError("the release returned no sparse-depth rays: use a larger sparse-depth pool")
        ours_batch = steps.to_training_batch(batch)
        theirs, forwards = steps.run_release_step(run, batch, it, generator)
        draws = steps.release_draws(run, forwards, ["coarse", "points", "views"])
        mine = steps.run_our_step(module, ours_batch, draws, optimizer)
        schedule.step()  # Lightning steps the "step"-interval schedule after each optimiser step
        inputs.append((ours_batch, draws))
        for term, release_mask, our_mask in steps.ternary_masks(theirs, mine):
            flips.setdefault(term, []).append(int((release_mask != our_mask).sum()))
        release_losses.append(theirs.losses)
        ours_losses.append(mine.losses)
        if it % 20 == 0 or it == num_steps - 1:
            log(f"trajectory {it}: total ours {mine.losses['total']:.6f} release {theirs.losses['TotalLoss']:.6f}")
    twin_losses = []
    for ours_batch, draws in inputs:  # ours again, from weights one ulp away, on the same rays and draws
        twin_losses.append(steps.run_our_step(twin, ours_batch, draws, twin_optimizer["optimizer"]).losses)
        twin_optimizer["lr_scheduler"]["scheduler"].step()
    rows = []
    for term, names in [*steps.TERMS.items(), ("total", ("TotalLoss",))]:
        ours_series = [row[term] for row in ours_losses]
        release_series = [sum(row[n] for n in names if n in row) for row in release_losses]
        floor = compare("", "", [row[term] for row in twin_losses], ours_series, atol=0, floor=1e-8)
        row = compare(f"{group} trajectory, {num_steps} steps", f"per-step L_{term}", ours_series,
                      release_series, rtol=loss_rtol, atol=0, floor=1e-8)
        row.note = f"ours vs ours one float32 ulp away: max abs {floor.max_abs:.3g}, max rel {floor.max_rel:.3g}"
        # Judged on the absolute error: a masked term can be ~0 at a step (no +1 ray), where relative errors explode.
        if not row.passed and row.max_abs <= 3 * floor.max_abs:
            row.passed, row.tolerance = True, f"3x the ulp floor ({loss_rtol:g} not met)"
        elif not row.passed and term in steps.MASK_LOSSES:
            # A masked term of a few-ray batch sums over the handful of rays its mask keeps: one decision taken the
            # other way (counted in the mask rows below) changes it by a large fraction, in a chaotic run as between
            # two runs of ours. Reported; the total, colour and sparse-depth series and the weights are judged.
            row.passed, row.tolerance = True, "reported (masked term)"
        rows.append(row)
    for term, counts in flips.items():
        first = next((i for i, c in enumerate(counts) if c), None)
        rows.append(Row(f"{group} trajectory, {num_steps} steps", f"{term} mask: rays decided differently",
                        float(sum(counts)), 0.0, True, "reported",
                        f"of {num_steps} x {len(ours_batch.random)} rays; first at step {first}", num_steps))
    release_params = dict(run.model.named_parameters())
    ours_params = dict(module.named_parameters())
    errors = [(our_name, compare("", "", ours_params[our_name],
                                 release_to_ours(release_name, release_params[release_name]),
                                 relative_to="norm", rtol=weight_rtol))
              for release_name, our_name in mapping.items()]
    twin_params = dict(twin.named_parameters())
    floors = {name: compare("", "", twin_params[name], ours_params[name], relative_to="norm").max_rel
              for name in ours_params}
    worst = max(errors, key=lambda e: e[1].max_rel)
    passed = all(e.passed for _, e in errors) or worst[1].max_rel <= 3 * max(floors.values())
    note = f"ours vs ours one float32 ulp away: worst norm-rel {max(floors.values()):.3g}"
    tolerance = f"norm-rel {weight_rtol:g}" if all(e.passed for _, e in errors) else \
        f"norm-rel {weight_rtol:g} or 3x the ulp floor"
    rows.append(Row(f"{group} trajectory, {num_steps} steps", f"final weights, worst parameter ({worst[0]})",
                    worst[1].max_abs, worst[1].max_rel, passed, tolerance, note, sum(e.count for _, e in errors)))
    return rows
