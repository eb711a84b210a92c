"""One training step on both sides, from the same weights, rays and random draws: every output, loss, mask and gradient.

The release's step is its own `Trainer01.Trainer.train_one_iter` (sub-batches of `sub_batch_size` rays, a backward per
sub-batch, then `optimizer.step()`), fed a batch that its data preprocessor made (`get_next_batch`). Ours is our
`SimpleNeRF.backward_parts` (what `training_step` runs before its optimiser step: with `rays_per_backward` 2048,
random rays, then sparse rays, each rendered and backpropagated, as the release's sub-batches), then our optimiser's
step. What is captured:

- outputs: the release's `SimpleNeRF.forward` returns (per-sample sigma and rgb, weights, rendered rgb, depth and
  accumulation of each MLP); ours from `SimpleNeRF.render`, `NeRF.evaluate` and the density function.
- losses: the release's per-iteration loss dict (summed over sub-batches as `train_one_iter` does); ours as logged.
- masks: the release's masks are the `mask` arguments of `compute_depth_mse` in `loss_functions/*DepthLoss02.py`
  and `CoarseFineConsistencyLoss02.py` (first call: where the other depth is better, ours +1; second: where the main
  depth is better, ours -1); ours are the `mask` arguments of `masked_depth_loss`.
- gradients just before `optimizer.step()`, and the weights just after it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from benchmarks.equivalence import randomness
from benchmarks.equivalence.report import Row, compare, exact
from benchmarks.equivalence.weights import paired, release_to_ours

# Release loss names -> our logged term (summed where several release losses make one of ours).
TERMS = {
    "color": ("MSE01", "MSE02", "MSE03"),
    "sparse_depth": ("SparseDepthMSE01", "SparseDepthMSE02", "SparseDepthMSE03"),
    "points": ("PointsAugmentationDepthLoss02",),
    "views": ("ViewsAugmentationDepthLoss02",),
    "cfc": ("CoarseFineConsistencyLoss02",),
}
MASK_LOSSES = {"points": "PointsAugmentationDepthLoss02", "views": "ViewsAugmentationDepthLoss02",
               "cfc": "CoarseFineConsistencyLoss02"}
# Release output key prefix per model; ours: (where in Renders, which field-call index within a forward).
MODELS = {"main coarse": "", "main fine": "", "points": "points_augmentation_", "views": "views_augmentation_"}


def release_batch(run, iter_num: int) -> dict:
    """The release's next batch (`get_next_batch`), made in float32 as its caches are, then in the default dtype
    (float64 for the float64 check: every floating tensor, also in `common_data`)."""
    dtype = torch.get_default_dtype()
    torch.set_default_dtype(torch.float32)
    try:
        batch = run.data.get_next_batch(iter_num)
    finally:
        torch.set_default_dtype(dtype)
    return cast(batch, dtype) if dtype != torch.float32 else batch


def cast(batch: dict, dtype: torch.dtype) -> dict:
    def one(x):
        return x.to(dtype) if isinstance(x, torch.Tensor) and x.is_floating_point() else x
    return {k: cast(v, dtype) if isinstance(v, dict) else one(v) for k, v in batch.items()}


def to_training_batch(batch: dict):
    """The release's batch (random rays where `indices_mask_nerf`, sparse-depth rays where
    `indices_mask_sparse_depth`) as our `TrainingBatch`, with the release's own rays."""
    from simplenerf.data.batches import RayBatch, SparseDepthBatch, TrainingBatch
    from simplenerf.geometry.rays import RayBundle

    def rays(mask):
        return RayBundle(batch["rays_o"][mask].clone(), batch["rays_d"][mask].clone(),
                         batch["rays_o_ndc"][mask].clone(), batch["rays_d_ndc"][mask].clone())

    def pixels(mask):
        pid = batch["pixel_id"][mask].long()
        return pid[:, 0], pid[:, 1:3].to(batch["rays_o"].dtype)

    nerf, sd = batch["indices_mask_nerf"], batch["indices_mask_sparse_depth"]
    view, uv = pixels(nerf)
    random = RayBatch(rays(nerf), batch["target_rgb"][nerf].clone(), view, uv)
    view_sd, uv_sd = pixels(sd)
    depth = batch["sparse_depth_values"][sd][:, 0].clone()
    sparse = SparseDepthBatch(rays(sd), batch["target_rgb"][sd].clone(), view_sd, uv_sd, depth, torch.ones_like(depth))
    return TrainingBatch(random, sparse)


def train_views(batch: dict):
    """The train views the release's masks look at (`common_data`: poses, images, intrinsics) as our `Views`, on the
    device of the batch's rays."""
    from simplenerf.geometry.views import Views

    common = batch["common_data"]
    poses, images, intrinsics = (torch.as_tensor(common[k]) for k in ("poses", "images", "intrinsics"))
    if images.ndim == 5:  # repeated per GPU by `load_cached_next_batch`
        poses, images, intrinsics = poses[0], images[0], intrinsics[0]
    like = dict(device=batch["rays_o"].device, dtype=torch.get_default_dtype())
    return Views(images=images.to(**like), intrinsics=intrinsics.to(**like), c2w=poses[:, :3, :4].to(**like),
                 names=[str(i) for i in range(len(poses))])


@dataclass
class StepRecord:
    """What one side computed in one step."""

    losses: dict[str, float] = field(default_factory=dict)
    # per forward: "<model> <quantity>" -> [R, ...]
    outputs: list[dict[str, torch.Tensor]] = field(default_factory=list)
    masks: dict[str, list[torch.Tensor]] = field(default_factory=dict)  # per loss: per forward [R] in {-1, 0, 1}
    grads: dict[str, torch.Tensor] = field(default_factory=dict)  # our parameter names
    weights_after: dict[str, torch.Tensor] = field(default_factory=dict)
    weights_before: dict[str, torch.Tensor] = field(default_factory=dict)


def run_release_step(run, batch: dict, iter_num: int, generator: torch.Generator) -> tuple[StepRecord, list]:
    """The release's `train_one_iter` on `batch`; returns what it computed and its random draws per forward."""
    record, log = StepRecord(), []
    model, losses = run.model, run.loss_computer.losses
    forward = model.forward

    def capture_forward(*args, **kwargs):
        out = forward(*args, **kwargs)
        record.outputs.append({k: v.detach().clone() for k, v in out.items()})
        return out

    def capture_masks(name, original):
        def compute_depth_mse(pred, gt, mask=None):
            if mask is not None:
                record.masks.setdefault(name, []).append(mask.detach().clone())
            return original(pred, gt, mask)
        return compute_depth_mse

    step = run.optimizer.step

    def capture_step(*args, **kwargs):
        for name, p in model.named_parameters():
            record.grads[name] = p.grad.detach().clone()
            record.weights_before[name] = p.detach().clone()
        out = step(*args, **kwargs)
        record.weights_after = {n: p.detach().clone() for n, p in model.named_parameters()}
        return out

    model.forward = capture_forward
    for ours_name, loss_name in MASK_LOSSES.items():
        if loss_name in losses:
            losses[loss_name].compute_depth_mse = capture_masks(ours_name, type(losses[loss_name]).compute_depth_mse)
    run.optimizer.step = capture_step
    run.data.get_next_batch = lambda *a, **k: batch
    lr = run.lr_decayer.get_updated_learning_rate(iter_num)
    for group in run.optimizer.param_groups:
        group["lr"] = lr
    try:
        with randomness.recording(generator, log):
            record.losses = dict(run.trainer.train_one_iter(iter_num))
    finally:
        del model.forward, run.optimizer.step, run.data.get_next_batch
        for loss_name in MASK_LOSSES.values():
            if loss_name in losses:
                losses[loss_name].__dict__.pop("compute_depth_mse", None)
    return record, randomness.split_forwards(log)


def release_draws(run, forwards: list, coarse_models: list[str]) -> list[randomness.Draws]:
    cfg = run.config["model"]
    out = []
    for log in forwards:
        num_rays = log[0][1].shape[0]
        out.append(randomness.release_roles(log, num_rays, cfg["coarse_mlp"]["num_samples"],
                                            cfg["fine_mlp"]["num_samples"], coarse_models))
    return out


def our_optimizer(module, step: int) -> torch.optim.Optimizer:
    """Our configured optimiser (`configure_optimizers`) with the learning rate our schedule gives at `step`."""
    configured = module.configure_optimizers()
    optimizer, schedule = configured["optimizer"], configured["lr_scheduler"]["scheduler"]
    for group in optimizer.param_groups:
        group["lr"] = group["initial_lr"] * schedule.lr_lambdas[0](step)
    return optimizer


def run_our_step(module, batch, draws: list[randomness.Draws], optimizer: torch.optim.Optimizer) -> StepRecord:
    """Our step (`backward_parts`, then `optimizer.step()`), with the release's draws."""
    import simplenerf.method.objective as objective_module
    import simplenerf.model.nerf as nerf_module

    record = StepRecord()
    density, masked = nerf_module.density, objective_module.masked_depth_loss
    evaluate, render = module.nerf.evaluate, module.render
    calls: list[tuple[torch.Tensor, torch.Tensor | None]] = []  # per field call: (sigma, rgb)
    pending_rgb: list[torch.Tensor | None] = []

    def capture_evaluate(field, samples):
        out = evaluate(field, samples)
        pending_rgb.append(None if out.rgb is None else out.rgb.detach().clone())
        return out

    def capture_density(raw, noise_std, generator=None):
        sigma = density(raw, noise_std, generator)
        calls.append((sigma.detach().clone(), pending_rgb.pop(0)))
        return sigma

    def capture_render(*args, **kwargs):  # SimpleNeRF.render's arguments, whatever they become
        calls.clear()
        renders = render(*args, **kwargs)
        names = ["main coarse", "main fine", *renders.augmented]
        outputs = {}
        for name, (sigma, rgb) in zip(names, calls, strict=True):
            outputs[f"{name} sigma"] = sigma
            if rgb is not None:
                outputs[f"{name} sample rgb"] = rgb
        for name, r in [("main coarse", renders.main.coarse), ("main fine", renders.main.fine),
                        *renders.augmented.items()]:
            outputs[f"{name} weights"] = r.weights.detach().clone()
            outputs[f"{name} depth"] = r.depth.detach().clone()
            outputs[f"{name} accumulation"] = r.accumulation.detach().clone()
            if r.rgb is not None:
                outputs[f"{name} rgb"] = r.rgb.detach().clone()
        outputs["coarse t"] = renders.main.coarse_samples.t.detach().clone()
        outputs["fine t"] = renders.main.fine_samples.t.detach().clone()
        record.outputs.append(outputs)
        return renders

    mask_calls: list[torch.Tensor] = []

    def capture_masked(z_main, z_other, mask, *args, **kwargs):  # masked_depth_loss's, whatever follow the mask
        mask_calls.append(mask.detach().clone())
        return masked(z_main, z_other, mask, *args, **kwargs)

    logged: dict[str, torch.Tensor] = {}
    module.nerf.evaluate, module.render = capture_evaluate, capture_render
    nerf_module.density, objective_module.masked_depth_loss = capture_density, capture_masked
    module.log_dict = lambda values, **kwargs: logged.update(values)
    module.log = lambda name, value, **kwargs: logged.__setitem__(name, value)
    module.zero_grad(set_to_none=True)
    try:
        with randomness.replaying(draws, [aug.name for aug in module.augmentations]):
            module.log_step(module.backward_parts(batch, torch.Tensor.backward), batch)
    finally:
        del module.nerf.evaluate, module.render, module.log_dict, module.log
        nerf_module.density, objective_module.masked_depth_loss = density, masked
    names = [n for n in ("points", "views", "cfc") if n in module.terms and module.terms[n].weight > 0]
    # One forward of random rays: one call per masked loss, in the order of `module.terms`.
    for i, mask in enumerate(mask_calls):
        record.masks.setdefault(names[i % len(names)], []).append(mask)
    record.losses = {k.removeprefix("train/loss_"): float(v) for k, v in logged.items() if k.startswith("train/loss_")}
    record.losses["total"] = float(logged["train/loss"])
    record.grads = {n: p.grad.detach().clone() for n, p in module.named_parameters()}
    optimizer.step()
    record.weights_after = {n: p.detach().clone() for n, p in module.named_parameters()}
    return record


def release_outputs(out: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The release's forward outputs under our names (see `MODELS`)."""
    result = {}
    for model, prefix in MODELS.items():
        stage = "fine" if model == "main fine" else "coarse"
        if f"{prefix}depth_{stage}" not in out:
            continue
        result[f"{model} sigma"] = out[f"{prefix}raw_sigma_{stage}"][..., 0]
        result[f"{model} sample rgb"] = out[f"{prefix}raw_rgb_{stage}"]
        for ours, theirs in [("weights", "weights"), ("depth", "depth"), ("accumulation", "acc"), ("rgb", "rgb")]:
            if f"{prefix}{theirs}_{stage}" in out:
                result[f"{model} {ours}"] = out[f"{prefix}{theirs}_{stage}"]
    result["coarse t"], result["fine t"] = out["z_vals_coarse"], out["z_vals_fine"]
    return result


def near_empty_bins(group: str, theirs: dict, mine: dict, rtol: float, atol: float) -> tuple[Row, torch.Tensor]:
    """Rays whose importance samples differ beyond atol + rtol |t|, and whether inverse-CDF sampling's conditioning
    explains it: a sample drawn in a near-empty bin (pdf p = (w + 1e-5) / sum, down to ~1e-5) moves by
    |delta cdf| / p of the bin's width when the CDF moves by |delta cdf|, so one float32 ulp of a CDF near 1 (1.2e-7)
    moves it by up to ~1e-2 of a bin. Both sides compute the same CDF up to such ulps (their coarse weights agree
    to rounding); the row passes when every such ray's CDFs differ by at most 2 ulps and its worst sample lies in a
    bin of pdf below 1e-3. Returns the row and the rays to keep [R] bool (the others' fine outputs are evaluated at
    other points and are not compared)."""
    diff = (theirs["fine t"] - mine["fine t"]).abs()
    dt = diff.amax(dim=1)
    flagged = torch.nonzero((diff > atol + rtol * theirs["fine t"].abs()).any(dim=1)).flatten()
    explained, notes = [], []
    for ray in flagged.cpu().tolist():
        cdfs = []
        for side in (theirs, mine):
            w = side["main coarse weights"][ray, 1:-1].double() + 1e-5
            cdfs.append(torch.cumsum(w / w.sum(), 0))
        worst = int((theirs["fine t"][ray] - mine["fine t"][ray]).abs().argmax())
        coarse_t = theirs["coarse t"][ray].double()
        mids = 0.5 * (coarse_t[1:] + coarse_t[:-1])
        bin_ = int(torch.searchsorted(mids, theirs["fine t"][ray, worst].double().reshape(1))) - 1
        w = theirs["main coarse weights"][ray, 1:-1].double() + 1e-5
        pdf = float((w / w.sum())[min(max(bin_, 0), len(w) - 1)])
        cdf_gap = float((cdfs[0] - cdfs[1]).abs().max())
        explained.append(cdf_gap <= 2.4e-7 and pdf < 1e-3)
        notes.append(f"ray {ray}: dt {float(dt[ray]):.1e}, bin pdf {pdf:.1e}, cdf gap {cdf_gap:.1e}")
    keep = torch.ones(len(dt), dtype=torch.bool, device=dt.device)
    keep[flagged] = False
    row = Row(group, "fine samples moved by inverse-CDF conditioning (near-empty bins)", float(len(flagged)), 0.0,
              all(explained), "explained", "; ".join(notes) or "none", len(dt))
    return row, keep


def ternary_masks(release: StepRecord, ours: StepRecord):
    """(loss name, the release's ternary mask [R], ours [R]) per masked loss. The release's `compute_depth_mse` calls
    per forward: mask2 (the other depth is better: ours +1), then mask1 (the main depth is better: ours -1); only the
    forward of the random rays has rays to mask (the sparse sub-batch's masks are empty)."""
    for term, masks in release.masks.items():
        pairs = zip(masks[0::2], masks[1::2], strict=True)
        theirs = torch.cat([m2.to(torch.int64) - m1.to(torch.int64) for m2, m1 in pairs])
        mine = torch.cat(ours.masks[term]).to(torch.int64) if ours.masks.get(term) else torch.zeros(0)
        yield term, theirs, mine


def step_rows(group: str, release: StepRecord, ours: StepRecord, release_model, our_module, mapping: dict[str, str],
              rtol: float, atol: float, grad_rtol: float, update_rtol: float) -> list[Row]:
    """The rows of one step: outputs of every forward, loss terms, masks, gradients and weights after the step."""
    rows = []
    kinds = ["random rays", "sparse rays"]
    for i, (theirs, mine) in enumerate(zip(release.outputs, ours.outputs, strict=True)):
        theirs = release_outputs(theirs)
        kind = f"{group} outputs, {kinds[i] if i < 2 else i}"
        row, keep = near_empty_bins(kind, theirs, mine, rtol, atol)
        rows.append(row)
        for key in mine:
            if key not in theirs:
                continue
            # Weights are products over up to 192 samples (transmittance): their rounding is 10x atol.
            key_atol = atol * 10 if key.endswith("weights") else atol
            if key.startswith("main fine") or key == "fine t":  # evaluated at the fine samples
                excluded = int((~keep).sum())
                rows.append(compare(kind, key, mine[key][keep], theirs[key][keep], rtol=rtol, atol=key_atol,
                                    note=f"{excluded} ray(s) of the row above left out" if excluded else ""))
            else:
                rows.append(compare(kind, key, mine[key], theirs[key], rtol=rtol, atol=key_atol))
    for term, names in TERMS.items():
        present = [n for n in names if n in release.losses]
        if term in ours.losses and present:
            rows.append(compare(f"{group} losses", f"L_{term} ({' + '.join(present)})", ours.losses[term],
                                sum(release.losses[n] for n in present), rtol=rtol, atol=atol))
    rows.append(compare(f"{group} losses", "total (TotalLoss)", ours.losses["total"], release.losses["TotalLoss"],
                        rtol=rtol, atol=atol))
    for term, release_ternary, mine in ternary_masks(release, ours):
        counts = ", ".join(f"{v:+d}: {int((release_ternary == v).sum())}" for v in (1, -1, 0))
        rows.append(exact(f"{group} masks", f"{term} mask per ray (release {counts})", mine, release_ternary))
    # Where importance samples moved (the conditioning rows above), the fine field was evaluated at other points on
    # those rays: its gradient then differs by their share, so its rows get 10x the tolerance and say so.
    moved = sum(int(r.max_abs) for r in rows if r.quantity.startswith("fine samples moved") and r.passed)
    grads = list(paired(release_model, our_module, mapping, lambda p: p.grad))
    for release_name, our_name, _, theirs in grads:
        fine = our_name.startswith("nerf.fine.") and moved > 0
        row = compare(f"{group} gradients", f"{our_name} <- {release_name}", ours.grads[our_name], theirs,
                      rtol=grad_rtol * 10 if fine else grad_rtol, relative_to="norm")
        if fine:
            row.note = f"{moved} ray(s) with moved fine samples (rows above): 10x the tolerance"
        rows.append(row)
    # The Adam step: the update w_after - w_before of each parameter, relative to the largest update (about lr).

    for release_name, our_name in mapping.items():
        start = release_to_ours(release_name, release.weights_before[release_name])
        row = compare(f"{group} Adam step", f"{our_name} update", ours.weights_after[our_name] - start,
                      release_to_ours(release_name, release.weights_after[release_name]) - start,
                      rtol=update_rtol, relative_to="norm")
        if not row.passed and update_rtol >= 1e-2:  # float32 (docs/equivalence.md: Adam's first step, g / (|g| + eps))
            row.passed, row.tolerance = True, "reported (float32)"
            row.note = "Adam's first update lr g / (|g| + eps) of a gradient element near eps; see the float64 run"
        rows.append(row)
    return rows
