"""idp.thread_choice: one thread or all, chosen per call site by the times of its own calls."""

from __future__ import annotations

import numba
import pytest

from idp.thread_choice import ThreadChoice


def _many_threads() -> int:
    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # (set when numba loads)


def test_it_tries_both_ways_then_keeps_the_faster_and_rechecks_the_other():
    if _many_threads() < 2:
        pytest.skip("numba has one thread here: every call runs on it")
    choice = ThreadChoice(trials=3, recheck=10, window=4)
    seconds = {False: 2.0, True: 1.0}  # per unit of work: all threads twice as fast
    ways = []
    for _ in range(40):
        way = choice.parallel()
        ways.append(way)
        choice.record(way, seconds[way] * 100, work=100)
    assert ways[:6] == [False, True] * 3  # alternating, one thread first
    later = ways[6:]
    rechecks = [i for i, way in enumerate(later, start=6) if not way]
    assert rechecks == [10, 20, 30]  # the other way once every `recheck` calls
    assert choice.best() is True


def test_the_choice_follows_a_change_of_the_faster_way():
    """Work per call grows and the serial way becomes the faster: the rechecks see it, and the window forgets."""
    if _many_threads() < 2:
        pytest.skip("numba has one thread here: every call runs on it")
    choice = ThreadChoice(trials=2, recheck=4, window=2)
    for _ in range(8):
        way = choice.parallel()
        choice.record(way, 1.0 if way else 3.0, work=1)
    assert choice.best() is True
    for _ in range(40):
        way = choice.parallel()
        choice.record(way, 3.0 if way else 1.0, work=1)
    assert choice.best() is False


def test_one_numba_thread_means_one_way():
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        choice = ThreadChoice(trials=2)
        assert not any(choice.parallel() for _ in range(5))
    finally:
        numba.set_num_threads(before)


def test_run_sets_one_thread_for_the_serial_call_only_and_restores_it_after_an_error():
    if _many_threads() < 2:
        pytest.skip("numba has one thread here")
    before = numba.get_num_threads()
    seen = []

    def kernel():
        seen.append(numba.get_num_threads())
        return len(seen)

    choice = ThreadChoice(trials=1)
    assert choice.run(10, kernel) == 1  # first call: one thread
    assert choice.run(10, kernel) == 2  # second: all
    assert seen == [1, before]
    assert numba.get_num_threads() == before

    def failing():
        raise RuntimeError("in the kernel")

    serial = ThreadChoice(trials=1)
    with pytest.raises(RuntimeError, match="in the kernel"):
        serial.run(1, failing)
    assert numba.get_num_threads() == before
    assert serial.calls == 0  # a failed call is not timed


def test_an_explicit_serial_way_is_called_instead():
    choice = ThreadChoice(trials=1)
    assert choice.run(5, lambda: "all", lambda: "one") == "one"


def test_a_forced_way_is_always_taken():
    for way in (False, True):
        choice = ThreadChoice(force=way)
        assert all(choice.parallel() is way for _ in range(20))


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="trials"):
        ThreadChoice(trials=0)
