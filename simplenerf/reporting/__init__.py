"""Reporting tested runs: their records, tables beside the paper's scores, run comparisons."""
