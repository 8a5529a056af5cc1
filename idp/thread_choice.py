"""Whether a kernel runs on all of numba's threads or on one, chosen per call site by timing both on this machine.

A few kernels split small amounts of work over numba's threads (``prange``), where waking the OpenMP workers can
cost more than it saves: on the 2-vCPU Intel VM a parallel region costs ~0.1–0.2 ms (workers sleep at once,
``OMP_WAIT_POLICY=PASSIVE``, see idp/__init__.py), and bunny_700's collision compaction took 0.23 ms a call on one
thread against 0.63 ms on two, its contact-block scatter 1.05 against 1.83 ms; on the AMD VM the same scatter at
bunny_3376 was faster on two threads (2.0 → 1.55 ms). Both ways give the same results bit for bit (these kernels'
outputs do not depend on the thread count), so the choice is one of speed alone, and measuring it where the run
happens beats a size threshold tuned on another machine: a :class:`ThreadChoice` alternates the two ways for its
first calls, then keeps the one with the lower median time per unit of work over its recent calls, and tries the
other way again once every ``recheck`` calls, as the scene's sizes change.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import TypeVar

import numba

T = TypeVar("T")

__all__ = ["ThreadChoice"]


class ThreadChoice:
    """The faster of "all threads" and "one thread" for one call site, from the times of its own calls."""

    def __init__(self, trials: int = 4, recheck: int = 64, window: int = 8, force: bool | None = None):
        """``trials`` calls of each way first (alternating, one thread first); afterwards the way with the lower
        median seconds per unit of work over the last ``window`` calls of each, and the other way once every
        ``recheck`` calls. ``force``: always all threads (True) or always one (False) instead (tests comparing the
        two ways, measurements of one)."""
        if trials < 1 or recheck < 2 or window < 1:
            raise ValueError("trials >= 1, recheck >= 2 and window >= 1 are needed")
        self.trials, self.recheck, self.window = int(trials), int(recheck), int(window)
        self.force = force
        self._per_work: dict[bool, list[float]] = {False: [], True: []}  # parallel? -> recent seconds per work
        self.calls = 0

    def parallel(self) -> bool:
        """Whether the next call runs on every thread (False whenever numba has one thread)."""
        if self.force is not None:
            return self.force
        if numba.get_num_threads() <= 1:
            return False
        if self.calls < 2 * self.trials:
            return self.calls % 2 == 1
        best = self.best()
        return (not best) if self.calls % self.recheck == 0 else best

    def best(self) -> bool:
        """The way chosen now: True (all threads) when its recent median time per unit of work is the lower."""
        serial, parallel = self._per_work[False], self._per_work[True]
        if not parallel or not serial:
            return bool(parallel) and not serial
        return statistics.median(parallel) < statistics.median(serial)

    def record(self, parallel: bool, seconds: float, work: int) -> None:
        """One call's wall time and its amount of work (items), for the way it ran."""
        self.calls += 1
        recent = self._per_work[bool(parallel)]
        recent.append(seconds / max(int(work), 1))
        del recent[: -self.window]

    def run(self, work: int, on_all: Callable[[], T], on_one: Callable[[], T] | None = None) -> T:
        """``on_all()`` or ``on_one()`` as :meth:`parallel` says, timed and recorded. ``on_one`` defaults to
        ``on_all`` with numba's thread count set to 1 for the calling thread during the call (``prange`` loops
        then run on it alone)."""
        parallel = self.parallel()
        t0 = time.perf_counter()
        if parallel:
            out = on_all()
        elif on_one is not None:
            out = on_one()
        else:
            threads = numba.get_num_threads()
            numba.set_num_threads(1)
            try:
                out = on_all()
            finally:
                numba.set_num_threads(threads)
        self.record(parallel, time.perf_counter() - t0, work)
        return out
