"""Host memory: keep freed memory for reuse instead of handing it back to the operating system.

A training step allocates and frees dozens of large activation tensors (hundreds of MB each at the paper's scale).
glibc serves every allocation above 32 MB with a fresh mmap and unmaps it on free, so each step page-faults all of
its activations in again, and the kernel zero-fills every page. On this project's 2-core CPU that was a third of a
paper-config step's CPU time (512 + 512 rays: 8.8 s of system time per step against 14 s of user time, 3.9 M page
faults; with freed memory kept: 0.5 to 1.3 s, 60 k to 180 k faults). Keeping freed memory in the heap makes later steps
reuse the same pages, but a heap cannot give back or merge blocks freed in its middle, so the process grows: the
paper's SimpleNeRF config (2048 + 2048 rays) reached 12.7 GiB in bf16 at 41 s per step, but in fp32 it passed 24 GiB and
was killed (out of memory), where glibc's default peaks near 18 GiB. So it is opt-in: SIMPLENERF_MALLOC=reuse.
Nothing happens on other C libraries or systems.
"""

from __future__ import annotations

import ctypes
import os
import sys

M_TRIM_THRESHOLD = -1  # mallopt parameters of glibc's malloc.h
M_MMAP_MAX = -4


def reuse_freed_memory() -> bool:
    """With SIMPLENERF_MALLOC=reuse, tells glibc's malloc to serve large blocks from the heap (no mmap) and to keep up
    to 2 GiB of freed memory at the heap's top. Returns whether it applied (never on non-glibc systems)."""
    if os.environ.get("SIMPLENERF_MALLOC") != "reuse" or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):  # not glibc (e.g. musl)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, 0)) and bool(mallopt(M_TRIM_THRESHOLD, 2**31 - 1))
