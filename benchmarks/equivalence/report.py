"""The equivalence table: one row per checked quantity, with its max absolute and relative error and PASS / FAIL.

A row compares two arrays of the same shape (ours, the release's). The relative error is |a - b| / max(|b|, floor),
maximised over elements, with `floor` a magnitude below which a value counts as zero (so that a difference of 1e-9 on
a value of 1e-12 is not a relative error of 1e3). A row passes when every element is within atol + rtol |b|
(numpy.isclose's rule). Exact quantities (indices, mask decisions) use atol = rtol = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Row:
    group: str  # e.g. "data fern 2v", "model", "losses", "gradients"
    quantity: str  # e.g. "c2w", "main coarse weights", "L_cfc"
    max_abs: float
    max_rel: float
    passed: bool
    tolerance: str  # e.g. "rtol 1e-5 atol 1e-6", "exact"
    note: str = ""  # e.g. "deliberate difference, switched to the release's behaviour: ..."
    count: int = 0  # number of compared values


def _as_array(x) -> np.ndarray:
    try:
        import torch

        if isinstance(x, torch.Tensor):
            x = x.detach().cpu().double().numpy()
    except ImportError:  # pragma: no cover
        pass
    return np.asarray(x, dtype=np.float64)


def compare(group: str, quantity: str, ours, release, rtol: float = 1e-5, atol: float = 1e-6, floor: float = 1e-6,
            note: str = "", relative_to: str = "element") -> Row:
    """One row: ours vs the release's values (any array-likes or tensors of equal shape).

    `relative_to="max"`: errors relative to the largest |value| of the release's tensor: passes when
    max |a - b| <= rtol max |b|. `relative_to="norm"`: the tensor's relative error ||a - b|| / ||b|| <= rtol (a
    gradient is a sum over many samples; the rows then show the max abs error beside it).
    """
    a, b = _as_array(ours), _as_array(release)
    if a.shape != b.shape:
        return Row(group, quantity, math.inf, math.inf, False, "shape", f"shape {a.shape} vs release {b.shape}. {note}")
    if a.size == 0:
        return Row(group, quantity, 0.0, 0.0, True, "-", f"no values. {note}".strip(), 0)
    finite_a, finite_b = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(finite_a, finite_b) or not np.array_equal(a[~finite_a], b[~finite_b]):
        return Row(group, quantity, math.inf, math.inf, False, "finite", f"non-finite values differ. {note}", a.size)
    a, b = a[finite_a], b[finite_b]
    diff = np.abs(a - b)
    max_abs = float(diff.max()) if diff.size else 0.0
    if relative_to == "norm":  # ||a - b|| / ||b||: a whole tensor's relative error
        max_rel = float(np.linalg.norm(a - b) / max(float(np.linalg.norm(b)), floor))
        return Row(group, quantity, max_abs, max_rel, max_rel <= rtol, f"norm-rel {rtol:g}", note, int(a.size))
    if relative_to == "max":
        scale = float(np.abs(b).max()) if b.size else 0.0
        max_rel = max_abs / max(scale, floor)
        return Row(group, quantity, max_abs, max_rel, max_rel <= rtol, f"max-rel {rtol:g}", note, int(a.size))
    max_rel = float((diff / np.maximum(np.abs(b), floor)).max()) if diff.size else 0.0
    passed = bool(np.all(diff <= atol + rtol * np.abs(b)))
    tolerance = "exact" if rtol == 0 and atol == 0 else f"rtol {rtol:g} atol {atol:g}"
    return Row(group, quantity, max_abs, max_rel, passed, tolerance, note, int(a.size))


def exact(group: str, quantity: str, ours, release, note: str = "") -> Row:
    """A row for values that must be identical (indices, frame numbers, mask decisions)."""
    return compare(group, quantity, ours, release, rtol=0.0, atol=0.0, note=note)


def flag(group: str, quantity: str, passed: bool, note: str) -> Row:
    """A row for a check that is a yes / no (e.g. a listed deliberate difference that is switched off)."""
    return Row(group, quantity, 0.0, 0.0, passed, "-", note)


@dataclass
class Report:
    rows: list[Row] = field(default_factory=list)

    def add(self, *rows: Row) -> None:
        self.rows.extend(rows)

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.rows)

    def markdown(self) -> str:
        lines = ["| group | quantity | values | max abs error | max rel error | tolerance | result | note |",
                 "|---|---|---:|---:|---:|---|---|---|"]
        for r in self.rows:
            lines.append(f"| {r.group} | {r.quantity} | {r.count} | {r.max_abs:.3g} | {r.max_rel:.3g} | {r.tolerance} "
                         f"| {'PASS' if r.passed else 'FAIL'} | {r.note} |")
        failed = sum(not r.passed for r in self.rows)
        lines.append("")
        summary = f"{len(self.rows) - failed} of {len(self.rows)} rows pass"
        lines.append(summary + (f", {failed} FAIL" if failed else ""))
        return "\n".join(lines)


def summary(table: str) -> str:
    """Per group of a printed table (`Report.markdown`): rows, rows passed, the worst max absolute and relative
    errors (relative errors of values near zero are large where the row's atol passes them)."""
    groups: dict[str, list[tuple[float, float, bool]]] = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 7 or cells[0] in ("group", "---") or cells[6] not in ("PASS", "FAIL"):
            continue
        group = cells[0]
        for word in (" outputs", " losses", " masks", " gradients", " Adam step", " optimiser", " trajectory"):
            if word in group:
                group = group[: group.index(word) + len(word)]
        groups.setdefault(group, []).append((float(cells[3]), float(cells[4]), cells[6] == "PASS"))
    lines = ["| group | rows | pass | worst max abs error | worst max rel error |", "|---|---:|---:|---:|---:|"]
    for group, rows in groups.items():
        worst_abs, worst_rel = max(r[0] for r in rows), max(r[1] for r in rows)
        lines.append(f"| {group} | {len(rows)} | {sum(r[2] for r in rows)} | {worst_abs:.3g} | {worst_rel:.3g} |")
    return "\n".join(lines)


if __name__ == "__main__":  # python -m benchmarks.equivalence.report TABLE.md: the per-group summary
    import sys

    print(summary(open(sys.argv[1]).read()))
