"""The parameter-name map between the release's `SimpleNeRF01` and our `SimpleNeRF` (the paper's configs).

Release (`models/SimpleNeRF01.py`, class `MLP`): `pts_linears.0..7` (the trunk; the input is concatenated again after
layer 4's ReLU as `cat([input_pts, h])`, so layer 5 has fan-in input + 256 with the input's columns FIRST),
`pts_output_linear` (density, or density + RGB for the views augmentation), `feature_linear`, `views_linears.0` (the
colour branch's hidden layer) and `views_output_linear` (RGB). Ours (`simplenerf/model/fields.py`,
`RadianceField`): `trunk.0..7` with layer 5 reading `cat([h, x])` (input columns LAST), `density_head` or `output`,
`feature`, `color.0`, `color.2`. The two layer-5 weight layouts are column permutations of each other; everything
else is the same tensor under another name.

Models: release `coarse_model` / `fine_model` / `pts_aug_coarse_model` / `views_aug_coarse_model` -> ours
`nerf.coarse` / `nerf.fine` / the augmentation named "points" / the one named "views".
"""

from __future__ import annotations

from collections.abc import Callable

import torch

SKIP = 5  # the trunk layer that reads the encoded input again (release: index 4 in `skips`, i.e. list index 5)

MODELS = {"coarse_model": "nerf.coarse", "fine_model": "nerf.fine"}
AUGMENTATIONS = {"pts_aug_coarse_model": "points", "views_aug_coarse_model": "views"}


def _layer(release_layer: str, view_dependent: bool) -> str:
    if release_layer.startswith("pts_linears."):
        return "trunk." + release_layer.split(".", 1)[1]
    return {
        "pts_output_linear": "density_head" if view_dependent else "output",
        "feature_linear": "feature",
        "views_linears.0": "color.0",
        "views_output_linear": "color.2",
    }[release_layer]


def name_map(ours: torch.nn.Module) -> dict[str, str]:
    """release parameter name -> our parameter name, for every parameter of both models (checked: a bijection)."""
    augmentation_index = {aug.name: i for i, aug in enumerate(ours.augmentations)}
    prefixes = dict(MODELS)
    prefixes.update({k: f"augmentations.{augmentation_index[v]}.field" for k, v in AUGMENTATIONS.items()
                     if v in augmentation_index})
    mapping = {}
    ours_params = dict(ours.named_parameters())
    for release_prefix, our_prefix in prefixes.items():
        field = ours.get_submodule(our_prefix)
        for name in ("weight", "bias"):
            for layer in [f"pts_linears.{i}" for i in range(len(field.trunk))] + [
                "pts_output_linear", "feature_linear", "views_linears.0", "views_output_linear"
            ]:
                if not field.view_dependent and layer in ("feature_linear", "views_linears.0", "views_output_linear"):
                    continue
                target = f"{our_prefix}.{_layer(layer, field.view_dependent)}.{name}"
                mapping[f"{release_prefix}.{layer}.{name}"] = target
    missing = set(ours_params) - set(mapping.values())
    if missing:
        raise ValueError(f"our parameters without a release counterpart: {sorted(missing)}")
    return mapping


def _skip_width(release_name: str, tensor: torch.Tensor) -> int | None:
    """The encoded input's width where `release_name` is the skip layer's weight, else None."""
    if release_name.endswith(f"pts_linears.{SKIP}.weight"):
        return tensor.shape[1] - tensor.shape[0]  # fan-in = input + width, width = fan-out
    return None


def release_to_ours(release_name: str, tensor: torch.Tensor) -> torch.Tensor:
    """A release parameter (or its gradient) in our layout: layer 5's columns [input | h] -> [h | input]."""
    width = _skip_width(release_name, tensor)
    if width is None:
        return tensor
    return torch.cat([tensor[:, width:], tensor[:, :width]], dim=1)


def copy_release_weights(release: torch.nn.Module, ours: torch.nn.Module) -> dict[str, str]:
    """Copies every parameter of the release's model into ours (in place); returns the name map."""
    mapping = name_map(ours)
    release_params = dict(release.named_parameters())
    unmapped = set(release_params) - set(mapping)
    if unmapped:
        raise ValueError(f"release parameters without a counterpart of ours: {sorted(unmapped)}")
    ours_params = dict(ours.named_parameters())
    with torch.no_grad():
        for release_name, our_name in mapping.items():
            value = release_to_ours(release_name, release_params[release_name].detach())
            if value.shape != ours_params[our_name].shape:
                shape = tuple(ours_params[our_name].shape)
                raise ValueError(f"{release_name} {tuple(value.shape)} vs {our_name} {shape}")
            ours_params[our_name].copy_(value)
    return mapping


def paired(release: torch.nn.Module, ours: torch.nn.Module, mapping: dict[str, str],
           get: Callable[[torch.nn.Parameter], torch.Tensor | None]):
    """(release name, ours name, our value, the release's value in our layout) for every parameter, where `get`
    (e.g. `lambda p: p.grad`) returns a tensor on both sides."""
    release_params, ours_params = dict(release.named_parameters()), dict(ours.named_parameters())
    for release_name, our_name in mapping.items():
        a, b = get(ours_params[our_name]), get(release_params[release_name])
        yield release_name, our_name, a, None if b is None else release_to_ours(release_name, b)
