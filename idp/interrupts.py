"""Interrupts honoured at safe points while a run is stepping.

A signal handler that raises runs at whatever bytecode the main thread is on — also inside numba's and ipctk's
Python-level glue (argument unboxing, typeof), where an exception can surface as a ``SystemError`` ("returned a
result with an exception set") instead of the interrupt, and a run that was told to stop then exits with a
traceback and without its summary. So while a run is stepping (:func:`deferred`) a first SIGTERM or Ctrl-C is only
recorded, and the stepper and the Newton loop raise it at :func:`checkpoint` — the start of each step and of
each Newton iteration, at most one iteration late; a second signal raises at once (the user insists). What a
signal does outside a run is the caller's choice (the CLI ends the process at once: nothing unfinished is lost
then, and raising inside an import or numba's glue would show an unrelated error).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

_depth = 0
_immediate = 0
_pending: KeyboardInterrupt | None = None


def request(exc: KeyboardInterrupt) -> None:
    """Called by a signal handler: record ``exc`` inside a run (raised at the next checkpoint), else raise it."""
    global _pending
    if _depth > 0 and _pending is None:
        _pending = exc
        return
    _pending = None
    raise exc


def checkpoint() -> None:
    """Raise the interrupt recorded since the last checkpoint, if any (a safe point of the stepping loop)."""
    global _pending
    exc = _pending
    if exc is not None:
        _pending = None
        raise exc


def handled() -> bool:
    """True inside :func:`deferred` or :func:`immediate`: a signal becomes an exception here (now or later)."""
    return _depth > 0 or _immediate > 0


def pending() -> bool:
    """True when an interrupt has been recorded and not raised yet."""
    return _pending is not None


@contextmanager
def deferred() -> Iterator[None]:
    """Inside: a first signal waits for the next :func:`checkpoint`. An interrupt still recorded when the
    outermost block ends is dropped: the stepping it would have stopped is over, and what follows is short."""
    global _depth, _pending
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0:
            _pending = None


@contextmanager
def immediate() -> Iterator[None]:
    """Inside: a signal raises at once (unless a :func:`deferred` block is open too) — for loops that only wait on
    other processes and clean up on ``KeyboardInterrupt`` themselves, e.g. a batch stopping its jobs."""
    global _immediate
    _immediate += 1
    try:
        yield
    finally:
        _immediate -= 1
