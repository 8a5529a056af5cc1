"""Run a compiled kernel over the parts of an index range on threads, instead of numba's ``prange``.

A kernel written as ``kernel(i0, i1, *args)`` (``@njit(nogil=True)``: it releases the GIL) that handles the items
``[i0, i1)`` and writes only their own outputs is split here into one contiguous part per numba thread
(:func:`numba.get_num_threads`, so ``NUMBA_NUM_THREADS`` and :func:`numba.set_num_threads` apply as to ``prange``):
the calling thread runs the first part and persistent worker threads the others. Each item is computed by the same code
whatever the split, so results do not depend on the thread count.

Why not ``prange``: numba compiles a ``prange`` loop's body into a function of its own and links and optimises every
callee into it once more, then again into the entry point. A serial kernel called from here is compiled once: the
barrier's Hessian pass took 24.4 s of compile work as a ``prange`` entry point and 12.3 s as its serial chunk
function (one process, empty cache, the 2-core Intel VM), on the first run of every machine. The hand-off costs
about 0.1 ms a call there (the operating system waking threads), against milliseconds of work in the kernels that
use it; a range shorter than two ``grain`` runs on the calling thread alone.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any


class _Worker:
    """A persistent thread that runs one part at a time, signalled by two locks (lighter than a queue and futures:
    a two-part call of a trivial kernel took 88 µs against ``ThreadPoolExecutor``'s 121 µs on the Intel VM, most of
    it the operating system waking the threads)."""

    def __init__(self) -> None:
        self._go = threading.Lock()
        self._go.acquire()
        self._done = threading.Lock()
        self._done.acquire()
        self._job: tuple[Callable[..., Any], tuple] | None = None
        self._error: BaseException | None = None
        threading.Thread(target=self._loop, daemon=True, name="idp-part").start()

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            assert self._job is not None
            kernel, args = self._job
            try:
                kernel(*args)
            except BaseException as exc:  # handed to the caller by wait()
                self._error = exc
            # the part's arguments are not kept while the thread waits for the next one: they held the last call's
            # arrays alive (bunnyx30_13K: the contact Hessian blocks, up to 73 MB, through the factorisation)
            del kernel, args
            self._job = None
            self._done.release()

    def start(self, kernel: Callable[..., Any], args: tuple) -> None:
        self._job = (kernel, args)
        self._go.release()

    def wait(self) -> BaseException | None:
        self._done.acquire()
        error, self._error = self._error, None
        return error


_workers: list[_Worker] = []
#: held by the call whose parts are on the workers; a second thread calling meanwhile runs its range alone
_in_use = threading.Lock()


def _forget_workers() -> None:  # a forked child has none of its parent's threads
    global _in_use
    _workers.clear()
    _in_use = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_workers)


def thread_count() -> int:
    """numba's thread count for the calling thread (what a ``prange`` loop here would use)."""
    import numba

    return int(numba.get_num_threads())


def run_in_parts(kernel: Callable[..., Any], n: int, *args: Any, grain: int = 1) -> None:
    """``kernel(i0, i1, *args)`` over ``[0, n)`` in one contiguous part per thread (parts of at least ``grain``
    items; one part, on the calling thread, when ``n < 2·grain``, with one thread, or while another thread's call
    has the workers). Returns when every part is done; an exception raised in any part is raised here, after all
    parts have finished."""
    if n <= 0:
        return
    parts = min(thread_count(), n // max(1, grain))
    if parts <= 1 or not _in_use.acquire(blocking=False):
        kernel(0, n, *args)
        return
    error: BaseException | None = None
    try:
        while len(_workers) < parts - 1:
            _workers.append(_Worker())
        bounds = [n * p // parts for p in range(parts + 1)]
        started = 0
        try:
            for p in range(1, parts):
                _workers[p - 1].start(kernel, (bounds[p], bounds[p + 1], *args))
                started = p
            try:
                kernel(bounds[0], bounds[1], *args)
            except BaseException as exc:
                error = exc
            for p in range(1, started + 1):  # every part finishes before anything is raised
                error = _workers[p - 1].wait() or error
        except BaseException:  # interrupted (Ctrl-C) while handing out or waiting: a worker may still be running
            _workers.clear()  # its part, so none of these is handed another; later calls start new ones
            raise
    finally:
        _in_use.release()
    if error is not None:
        raise error
