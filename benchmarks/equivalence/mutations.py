"""Do the fast tests catch what matters? Curated changes to the method, each applied alone to a copy of the
repository, then the fast tests run there; a change they do not fail is a hole in the tests. Run on demand:

    nice -n 10 python -m benchmarks.equivalence.mutations            # every mutation, the table in markdown
    nice -n 10 python -m benchmarks.equivalence.mutations --only e_tau_doubled --tests tests/method

Each mutation is one exact text substitution (its text must be found, so the list cannot silently go stale). The
table says, per mutation, whether the tests failed (caught), which failed and the seconds they took. The
unmutated copy runs first and must pass. docs/testing.md holds a dated result.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
FAST_TESTS = (
    "tests/method/test_pinned_step.py",
    "tests/method/test_reliability.py",
    "tests/method/test_losses.py",
    "tests/method/test_augmentations.py",
    "tests/geometry",
    "tests/test_configs.py",
)


@dataclass(frozen=True)
class Mutation:
    name: str
    what: str  # the change, in the paper's words
    file: str
    old: str
    new: str
    count: int = 1  # occurrences of `old` replaced (all must be there)


MUTATIONS = (
    Mutation("e_tau_doubled", "the reliability threshold e_tau doubled (eq. 6)", "simplenerf/method/reliability.py",
             "< threshold)", "< 2 * threshold)", 2),
    Mutation("not_strict", "e_other < e_main made <= (a tie trusts the other depth)",
             "simplenerf/method/reliability.py", "plus = (error_other < error_main)",
             "plus = (error_other <= error_main)"),
    Mutation("farthest_view", "patches reprojected into the farthest train view, not the nearest",
             "simplenerf/geometry/views.py", "distance.fill_diagonal_(math.inf)\n    return distance.argmin(dim=1)",
             "distance.fill_diagonal_(-math.inf)\n    return distance.argmax(dim=1)"),
    Mutation("stop_gradient_side", "the stop-gradient on the main depth instead of the reliable one (eq. 7)",
             "simplenerf/method/reliability.py", "(z_main - z_other.detach()).square()",
             "(z_main.detach() - z_other).square()"),
    Mutation("one_way_is_two_way", "one-way supervision trains both directions",
             "simplenerf/method/reliability.py", 'if direction == "bidirectional":',
             'if direction in ("bidirectional", "one_way"):'),
    Mutation("warm_up_5k", "the paper config's warm-up ends at step 5000, not 10000", "configs/llff.yaml",
             "[10000, 0.1]", "[5000, 0.1]", 3),
    Mutation("sparse_depth_on_coarse", "L_sd's target: the main coarse render instead of the fine one",
             "simplenerf/method/objective.py",
             "sparse_depth_loss([renders.main.fine, *renders.augmented.values()]",
             "sparse_depth_loss([renders.main.coarse, *renders.augmented.values()]"),
    Mutation("points_bands_4", "the points augmentation's density sees 4 bands, not l_p^ap = 3",
             "simplenerf/method/augmentations.py", "RadianceField(density_bands=3, residual_bands_to_color=True)",
             "RadianceField(density_bands=4, residual_bands_to_color=True)", 3),
    Mutation("views_view_dependent", "the views augmentation keeps its view directions",
             "simplenerf/method/augmentations.py", "RadianceField(view_dependent=False)",
             "RadianceField(view_dependent=True)", 3),
)


def copy_repo(dest: Path) -> Path:
    """The package, its tests and configs (what the tests read) in `dest`."""
    for part in ("simplenerf", "tests", "configs", "pyproject.toml"):
        source = REPO / part
        if source.is_dir():
            shutil.copytree(source, dest / part, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, dest / part)
    return dest


def apply(root: Path, mutation: Mutation) -> None:
    path = root / mutation.file
    text = path.read_text()
    found = text.count(mutation.old)
    if found != mutation.count:
        raise SystemExit(f"mutation {mutation.name}: expected {mutation.count} of {mutation.old!r} in {mutation.file}, "
                         f"found {found} (the code moved: update benchmarks/equivalence/mutations.py)")
    path.write_text(text.replace(mutation.old, mutation.new))


def run_tests(root: Path, tests: list[str]) -> tuple[bool, list[str], float]:
    """(passed, the failing tests, seconds) of the tests in the copy at `root`."""
    env = {**os.environ, "PYTHONPATH": str(root), "SIMPLENERF_SHARED": os.environ.get("SIMPLENERF_SHARED",
                                                                                      str(REPO.parent / "shared"))}
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", *tests],
                          cwd=root, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    failed = re.findall(r"^FAILED (\S+)", proc.stdout, re.M)
    if proc.returncode not in (0, 1) and not failed:
        failed = [f"(pytest exit {proc.returncode}: {proc.stdout.strip().splitlines()[-1:]})"]
    return proc.returncode == 0, failed, seconds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.equivalence.mutations", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=[m.name for m in MUTATIONS], help="these mutations only")
    ap.add_argument("--tests", nargs="+", default=list(FAST_TESTS), help="the tests run for each mutation")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="simplenerf_mutations_") as tmp:
        baseline = copy_repo(Path(tmp) / "baseline")
        passed, failures, seconds = run_tests(baseline, args.tests)
        print(f"unmutated: {'pass' if passed else 'FAIL ' + ' '.join(failures)} ({seconds:.0f} s)", file=sys.stderr,
              flush=True)
        if not passed:
            print("the unmutated copy must pass the tests first", file=sys.stderr)
            return 1
        for mutation in chosen:
            root = copy_repo(Path(tmp) / mutation.name)
            apply(root, mutation)
            passed, failures, seconds = run_tests(root, args.tests)
            rows.append((mutation, not passed, failures, seconds))
            print(f"{mutation.name}: {'caught' if not passed else 'NOT CAUGHT'} ({seconds:.0f} s)", file=sys.stderr,
                  flush=True)
            shutil.rmtree(root)
    print(f"tests: {' '.join(args.tests)}\n")
    print("| mutation | change | caught | failing tests | s |")
    print("|---|---|---|---|---:|")
    for mutation, caught, failures, seconds in rows:
        names = ", ".join(f.replace("tests/", "").replace(".py::", "::") for f in failures) or "-"
        print(f"| {mutation.name} | {mutation.what} | {'yes' if caught else '**no**'} | {names} | {seconds:.0f} |")
    return 0 if all(caught for _, caught, _, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
