"""idp.threaded: a compiled kernel run over parts of a range on threads gives what one call over the range gives."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest
from numba import njit

from idp import threaded

MAX_THREADS = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]


@njit(nogil=True, cache=False)
def _square_plus_part(i0, i1, a, out, first):  # pragma: no cover - compiled
    for i in range(i0, i1):
        out[i] = a[i] * a[i]
        first[i] = i0


@njit(nogil=True, cache=False)
def _fail_after(i0, i1, limit, out):  # pragma: no cover - compiled
    for i in range(i0, i1):
        out[i] = 1.0
    if i0 >= limit:
        raise ValueError("part past the limit")


def _run(n: int, threads: int, grain: int = 1) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(-1.0, 1.0, max(n, 1))
    out, first = np.full(max(n, 1), np.nan), np.full(max(n, 1), -1, np.int64)
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        threaded.run_in_parts(_square_plus_part, n, a, out, first, grain=grain)
    finally:
        numba.set_num_threads(previous)
    return out, first


@pytest.mark.parametrize("n", [1, 2, 7, 1000])
def test_every_item_once_whatever_the_thread_count(n: int) -> None:
    expected = np.linspace(-1.0, 1.0, n) ** 2
    for threads in sorted({1, MAX_THREADS}):
        out, first = _run(n, threads)
        np.testing.assert_array_equal(out[:n], expected)  # each item by the same code: identical
        parts = np.unique(first[:n])
        assert parts.size == min(threads, n)  # one contiguous part per thread
        assert parts[0] == 0


def test_a_range_below_two_grains_stays_on_the_calling_thread() -> None:
    if MAX_THREADS < 2:
        pytest.skip("one thread: every range is one part")
    _, first = _run(100, 2, grain=64)
    assert np.all(first[:100] == 0)
    _, first = _run(128, 2, grain=64)
    assert np.unique(first[:128]).tolist() == [0, 64]


def test_the_workers_keep_no_array_of_a_finished_call() -> None:
    """After a call returns, its arrays live only as long as the caller keeps them (a worker holding the last call's
    arguments kept the contact Hessian blocks alive through the next factorisation)."""
    if MAX_THREADS < 2:
        pytest.skip("needs two threads: one part runs on the calling thread")
    import gc
    import weakref

    previous = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        a = np.linspace(-1.0, 1.0, 1000)
        out, first = np.empty(1000), np.empty(1000, np.int64)
        threaded.run_in_parts(_square_plus_part, 1000, a, out, first)
        assert np.unique(first).size == 2  # the second part ran on a worker
        refs = [weakref.ref(v) for v in (a, out, first)]
        del a, out, first
        gc.collect()
        assert all(r() is None for r in refs)
    finally:
        numba.set_num_threads(previous)


def test_nothing_to_do() -> None:
    out, first = _run(0, MAX_THREADS)
    assert np.isnan(out).all() and (first == -1).all()


def test_an_error_in_a_part_is_raised_after_every_part_finished() -> None:
    if MAX_THREADS < 2:
        pytest.skip("needs two threads")
    out = np.zeros(100)
    with pytest.raises(ValueError, match="past the limit"):
        threaded.run_in_parts(_fail_after, 100, 1, out)  # the second part raises
    assert np.all(out == 1.0)  # the first part ran to its end
    threaded.run_in_parts(_fail_after, 100, 1000, out)  # the workers still serve later calls


def test_calls_from_two_threads_at_once() -> None:
    n = 200_000
    a = np.linspace(0.0, 1.0, n)
    results: list[np.ndarray] = []
    errors: list[BaseException] = []

    def call() -> None:
        try:
            for _ in range(20):
                out, first = np.empty(n), np.empty(n, np.int64)
                threaded.run_in_parts(_square_plus_part, n, a, out, first)
                results.append(out)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    callers = [threading.Thread(target=call) for _ in range(2)]
    for t in callers:
        t.start()
    for t in callers:
        t.join()
    assert not errors
    assert len(results) == 40
    for out in results:
        np.testing.assert_array_equal(out, a * a)


def test_a_wait_interrupted_by_ctrl_c_leaves_later_calls_right(monkeypatch) -> None:
    if MAX_THREADS < 2:
        pytest.skip("needs two threads")
    n = 2_000_000
    a = np.linspace(0.0, 1.0, n)
    out, first = np.empty(n), np.empty(n, np.int64)
    calls = []

    def interrupted(self):
        calls.append(1)
        raise KeyboardInterrupt  # as a signal arriving while the caller waits for the worker's part

    monkeypatch.setattr(threaded._Worker, "wait", interrupted)
    with pytest.raises(KeyboardInterrupt):
        threaded.run_in_parts(_square_plus_part, n, a, out, first)
    monkeypatch.undo()
    assert calls
    results: list[np.ndarray] = []

    def later_calls() -> None:  # the interrupted call's worker may still be busy: these must not be handed to it
        for _ in range(3):
            out = np.full(n, np.nan)
            threaded.run_in_parts(_square_plus_part, n, a, out, np.empty(n, np.int64))
            results.append(out)

    caller = threading.Thread(target=later_calls, daemon=True)
    caller.start()
    caller.join(timeout=120)
    assert not caller.is_alive(), "a later call never returned (handed to a worker still busy)"
    assert len(results) == 3
    for out in results:
        np.testing.assert_array_equal(out, a * a)
