"""Freed host memory is reused: repeated large allocations stop page-faulting once `reuse_freed_memory` applies.

Measured in a fresh interpreter, as in the CLI's process: the pytest process's heap is already fragmented by
everything the suite imported, which makes the page-fault counts there depend on the test order.
"""

import json
import os
import statistics
import subprocess
import sys

import pytest

from simplenerf.run.memory import reuse_freed_memory
from tests.conftest import REPO

PROBE = """
import json, resource, torch
from simplenerf.run.memory import reuse_freed_memory
applied = reuse_freed_memory()
torch.manual_seed(0)
mlp = torch.nn.Sequential(*[m for _ in range(4) for m in (torch.nn.Linear(64, 64), torch.nn.ReLU())])
x = torch.randn(2**18, 64)  # 64 MiB activations per layer
faults = []
for _ in range(5):  # a training step's pattern: many large blocks alive at once, freed, allocated again
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    mlp(x).square().mean().backward()
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps({"applied": applied, "faults": faults}))
"""


def probe(setting: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "SIMPLENERF_MALLOC"}
    if setting is not None:
        env["SIMPLENERF_MALLOC"] = setting
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_large_blocks_are_reused_instead_of_faulted_in_again():
    default, reused = probe(None), probe("reuse")
    assert not default["applied"] and reused["applied"]
    # glibc's default faults every round's activations in again (~330 k pages here); kept memory mostly settles to 0 to
    # 65536 pages a round, but one round in a few faults more (115 k seen under the suite's two workers), so the rounds
    # after the first are judged by their median: under a quarter of the default's fewest.
    assert min(default["faults"]) > 250_000, default
    assert statistics.median(reused["faults"][1:]) < min(default["faults"]) // 4, (reused, default)


def test_is_opt_in(monkeypatch):
    monkeypatch.delenv("SIMPLENERF_MALLOC", raising=False)
    assert not reuse_freed_memory()
