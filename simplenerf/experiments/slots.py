"""Slots for the jobs of a local sweep (`executors.run_here`): `concurrent_jobs` at a time, started in the order the
jobs became ready, as SLURM's queue would start them."""

from __future__ import annotations

import heapq
import threading
from contextlib import contextmanager


class ReadySlots:
    """`n` jobs at a time, the free slots handed out in the order the units became ready, ties in stage order (the
    index in `todo`): the order of SLURM's queue. A `threading.Semaphore` lets a unit whose needs just finished take
    the slot its need freed, ahead of units already waiting, and a waiting unit can lose its turn that way again and
    again (a fit left waiting while every later scene's fits and tests ran)."""

    def __init__(self, n: int) -> None:
        self.free, self.finished = n, 0  # free slots; jobs finished so far (the clock of readiness)
        self.waiting: list[tuple[int, int]] = []  # heap of (finished when it became ready, index)
        self.changed = threading.Condition()

    @contextmanager
    def slot(self, index: int):
        with self.changed:
            key = (self.finished, index)
            heapq.heappush(self.waiting, key)
            self.changed.wait_for(lambda: self.free > 0 and self.waiting[0] == key)
            heapq.heappop(self.waiting)
            self.free -= 1
            self.changed.notify_all()  # the next in line may find a slot free too
        try:
            yield
        finally:
            with self.changed:
                self.free += 1
                self.finished += 1
                self.changed.notify_all()
