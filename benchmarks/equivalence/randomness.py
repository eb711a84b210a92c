"""The same random draws on both sides: record the release's, replay them to ours by role.

A training forward draws, in the release (`models/SimpleNeRF01.py`): the stratified offsets `torch.rand([R, Sc])`
(`get_z_vals_coarse`), the density noise of the main coarse MLP, then of each augmentation's MLP, each as
`torch.randn([n, 1])` per `netchunk` points (`MLP.get_view_independent_outputs`), the importance-sampling quantiles
`torch.rand([R, Sf])` (`sample_pdf`), and the fine MLP's noise. Ours draws the same quantities in another order (coarse
offsets, coarse noise, quantiles, fine noise, then each augmentation's noise; `simplenerf/model/nerf.py`), each as one
tensor [R, S]. `Recorder` serves the release fresh values from a seeded generator and sorts them into roles;
`Replay` hands each role to our code at its own call, checking the shape, so both compute with identical
numbers. A mismatch in order or shape is an error, not a silent difference.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import torch


@dataclass
class Draws:
    """The random numbers of one forward pass of R rays, by role."""

    coarse_t: torch.Tensor  # [R, Sc] uniform
    pdf_u: torch.Tensor  # [R, Sf] uniform
    noise: dict[str, torch.Tensor] = field(default_factory=dict)  # model -> [R, S] standard normal


def _shape(args, kwargs) -> tuple[int, ...]:
    size = kwargs.get("size", args[0] if len(args) == 1 else args)
    if isinstance(size, torch.Size | list | tuple) and size and isinstance(size[0], int):
        return tuple(size)
    if isinstance(size, torch.Size | list | tuple) and size and isinstance(size[0], torch.Size | list | tuple):
        return tuple(size[0])
    return tuple(size)


@contextmanager
def recording(generator: torch.Generator, log: list[tuple[str, torch.Tensor]]):
    """Within: `torch.rand` / `torch.randn` draw from `generator` (default dtype) and append (kind, value) to `log`."""
    rand, randn = torch.rand, torch.randn

    def make(kind, fn):
        def draw(*args, **kwargs):
            dtype = kwargs.get("dtype") or torch.get_default_dtype()
            value = fn(_shape(args, kwargs), generator=generator, dtype=dtype)
            log.append((kind, value))
            return value.clone()
        return draw

    torch.rand, torch.randn = make("rand", rand), make("randn", randn)
    try:
        yield
    finally:
        torch.rand, torch.randn = rand, randn


def release_roles(log: list[tuple[str, torch.Tensor]], num_rays: int, num_coarse: int, num_fine: int,
                  coarse_models: list[str]) -> Draws:
    """Sorts one release forward's log into roles. `coarse_models`: the MLPs evaluated at the coarse samples in the
    release's order (main coarse, then the augmentations as its `render_rays` runs them)."""
    kinds = [k for k, _ in log]
    if kinds.count("rand") != 2 or kinds[0] != "rand":
        raise AssertionError(f"unexpected draws in a release forward: {kinds[:8]}... ({len(kinds)})")
    second = kinds.index("rand", 1)
    coarse_noise = torch.cat([v.reshape(-1) for k, v in log[1:second]])
    fine_noise = torch.cat([v.reshape(-1) for k, v in log[second + 1 :]])
    per_model = num_rays * num_coarse
    fine_size = num_rays * (num_coarse + num_fine)
    if coarse_noise.numel() != per_model * len(coarse_models) or fine_noise.numel() != fine_size:
        raise AssertionError(f"noise sizes {coarse_noise.numel()}, {fine_noise.numel()} do not match {num_rays} rays "
                             f"x {num_coarse}+{num_fine} samples and models {coarse_models}")
    noise = {name: coarse_noise[i * per_model : (i + 1) * per_model].reshape(num_rays, num_coarse)
             for i, name in enumerate(coarse_models)}
    noise["fine"] = fine_noise.reshape(num_rays, num_coarse + num_fine)
    draws = Draws(coarse_t=log[0][1].reshape(num_rays, num_coarse), pdf_u=log[second][1].reshape(num_rays, num_fine),
                  noise=noise)
    return draws


def split_forwards(log: list[tuple[str, torch.Tensor]]) -> list[list[tuple[str, torch.Tensor]]]:
    """The log of several forwards, one list per forward (each forward draws `rand` exactly twice)."""
    forwards: list[list] = []
    for kind, value in log:
        if not forwards or (kind == "rand" and sum(k == "rand" for k, _ in forwards[-1]) == 2):
            forwards.append([])
        forwards[-1].append((kind, value))
    return forwards


@contextmanager
def replaying(draws: list[Draws], augmentations: list[str]):
    """Within: our forwards take `draws` in order. Ours per forward: rand coarse_t, randn coarse, rand pdf_u,
    randn fine, then randn of each augmentation in `augmentations` order (`SimpleNeRF.render`)."""
    queue: list[tuple[str, torch.Tensor]] = []
    for d in draws:
        queue += [("rand", d.coarse_t), ("randn", d.noise["coarse"]), ("rand", d.pdf_u), ("randn", d.noise["fine"])]
        queue += [("randn", d.noise[name]) for name in augmentations]
    rand, randn = torch.rand, torch.randn

    def make(kind):
        def draw(*args, **kwargs):
            if not queue:
                raise AssertionError(f"our code drew torch.{kind} more often than the release")
            want, value = queue.pop(0)
            shape = _shape(args, kwargs)
            if want != kind or tuple(value.shape) != shape:
                raise AssertionError(f"our torch.{kind}{shape} met the release's {want}{tuple(value.shape)}")
            return value.to(dtype=kwargs.get("dtype") or value.dtype, device=kwargs.get("device") or value.device)
        return draw

    torch.rand, torch.randn = make("rand"), make("randn")
    try:
        yield queue
    finally:
        torch.rand, torch.randn = rand, randn
    if queue:
        raise AssertionError(f"{len(queue)} of the release's draws were not used by ours")
