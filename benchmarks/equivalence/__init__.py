"""Numerical equivalence of this codebase with the authors' release (github NagabhushanSN95/SimpleNeRF, c429746).

Benchmark-side code, not shipped in the package: it imports the release's own modules from a copy outside this
repository (never its code copied here) and compares, quantity by quantity, what both compute from the same inputs.
`python -m benchmarks.equivalence.check` is the command; `report.py` holds the table every check writes rows into.
"""
