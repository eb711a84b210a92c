"""What is checked before a sweep's jobs are submitted, since a job can only find it out hours or days later on a
compute node: every scene (and reference depth folder) readable from the folder the jobs start in, the LPIPS
weights resolvable without network (the tests score LPIPS; compute nodes are often offline), the W&B mode stated
for SLURM jobs (`wandb.mode` in the sweep file or WANDB_MODE: offline when the nodes cannot reach W&B), and the output
folder writable. One line per problem; with any, nothing is submitted (`PreflightError`, raised by the command).
"""

from __future__ import annotations

import os
from pathlib import Path

from simplenerf.experiments.plan import Plan
from simplenerf.experiments.spec import NO_DEPTH, SCENE_DEPTH, SweepError, scene_name

NODE_LOCAL = ("/tmp", "/dev/shm", "/var/tmp")
"""Paths that are the submitting machine's own, not the compute nodes'."""


class PreflightError(SweepError):
    """The sweep would fail on its nodes; the message has one line per problem."""


def _readable(path: Path) -> bool:
    return os.access(path, os.R_OK | (os.X_OK if path.is_dir() else 0))


def scene_problems(plan: Plan) -> list[str]:
    problems = []
    for i, scene in enumerate(plan.sweep.scenes):
        name, path = scene_name(scene), Path(scene.path)
        needed = [path / "poses_bounds.npy"] if scene.format == "llff" else [path / f"{path.name}.txt",
                                                                             path / "frames"]
        if not path.is_dir() or not _readable(path):
            problems.append(f"scenes[{i}] ({name}): {path} is not a readable folder from {Path.cwd()} (the jobs' "
                            "working directory)")
            continue
        for f in needed:
            if not f.exists() or not _readable(f):
                problems.append(f"scenes[{i}] ({name}): {f} is missing or not readable ({scene.format} scenes have it)")
        ref = scene.reference_depth
        if ref not in (None, SCENE_DEPTH, NO_DEPTH) and (not Path(ref).is_dir() or not _readable(Path(ref))):
            problems.append(f"scenes[{i}] ({name}): reference_depth {ref} is not a readable folder")
    return problems


def lpips_problems(plan: Plan) -> list[str]:
    """The LPIPS weights of every test that scores LPIPS, resolved as the test will, without a download."""
    from simplenerf.metrics.lpips import LPIPSWeightsNotFound, _resolve_heads, _resolve_trunk

    problems, seen = [], set()
    for unit in plan.stage("test"):
        if not unit.extra.get("lpips", True):
            continue
        weights = unit.extra.get("lpips_weights")
        if weights in seen:
            continue
        seen.add(weights)
        try:
            _resolve_heads(_resolve_trunk(weights, allow_download=False))
        except (LPIPSWeightsNotFound, OSError, ValueError) as e:
            first = str(e).split(". ")[0]
            problems.append(f"LPIPS weights ({'--evaluation.lpips_weights ' + weights if weights else 'no path given'}"
                            f") cannot be found without network, as test {unit.key} needs them: {first}; set "
                            "SIMPLENERF_LPIPS_WEIGHTS=PATH (a path the nodes read) or put the file in the torch hub "
                            "cache")
    return problems


def wandb_problems(plan: Plan, executor: str) -> list[str]:
    if executor != "slurm" or plan.sweep.wandb.mode is not None or os.environ.get("WANDB_MODE"):
        return []
    if any("WANDB_MODE" in line for line in plan.sweep.resources.setup):
        return []
    return ["W&B mode not stated: set wandb.mode in the sweep file (offline when the compute nodes cannot reach "
            "api.wandb.ai, then `wandb sync` the runs' wandb/ folders; online; or disabled), or export WANDB_MODE"]


def output_problems(plan: Plan, executor: str) -> list[str]:
    folder = plan.output
    existing = next(p for p in [folder, *folder.parents] if p.exists())
    problems = []
    if not existing.is_dir():
        problems.append(f"output {folder}: {existing} is a file, not a folder")
    elif not os.access(existing, os.W_OK | os.X_OK):
        problems.append(f"output {folder}: {existing} is not writable")
    if executor == "slurm":
        for path in [folder, *(Path(s.path).resolve() for s in plan.sweep.scenes)]:
            if str(path).startswith(NODE_LOCAL):
                problems.append(f"{path} is on this machine's own disk ({'/'.join(path.parts[:2])[1:]}), which the "
                                "compute nodes do not see: use a shared file system")
    return problems


def preflight(plan: Plan, executor: str) -> list[str]:
    """Every problem found, one line each (empty: go)."""
    return [*scene_problems(plan), *lpips_problems(plan), *wandb_problems(plan, executor),
            *output_problems(plan, executor)]
