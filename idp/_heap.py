"""Garbage-collector settings for idp's own processes (the CLI's scene runs, the bench's scene runs).

A scene run's interpreter holds about 145K long-lived objects that numba, scipy, pydantic and ipctk create at
import and kernel-load time. Python's cyclic collector walks all of them in every full collection: once or twice
during a bunny_700 run (≈ 0.06 s) and several times while the interpreter shuts down (0.3–0.4 s of a 6 s
bunny_700 process on the 2-core VM; ``perf``: ``gc_collect_main``, ``visit_decref`` in the last 5 % of the
process). ``gc.freeze`` moves the objects alive at that moment out of the collector's generations, so later
collections only walk what was created after it. Nothing is freed later than before by reference counting; what
is skipped is collecting reference cycles among the frozen objects (at exit their memory goes with the process,
and CPython does not promise to run their finalizers at shutdown either). Atexit handlers, ``logging``'s flush
and the closing of files still run.

Libraries calling idp keep their own interpreter's behaviour: only the entry points of idp's processes (the
``idp`` command with the process's own arguments, the bench's child) call :func:`freeze_heap_at_exit`, and
:func:`freeze_startup_heap` does nothing in a process that did not (a test session calling ``idp.cli.main``
many times would otherwise keep every run's cyclic garbage).
"""

from __future__ import annotations

import atexit
import gc

_own_process = False  # set by freeze_heap_at_exit: this process is one of idp's own


def freeze_heap_at_exit() -> None:
    """Register ``gc.freeze`` as an exit handler, once per process, and mark the process as idp's own. atexit
    runs handlers last-in first-out, so everything the run registers later (progress bars, writers) finishes
    before the freeze."""
    global _own_process
    if not _own_process:
        atexit.register(gc.freeze)
        _own_process = True


def freeze_startup_heap() -> None:
    """In idp's own processes, freeze what the imports created (right before the process's one scene run), so
    the run's full collections do not walk the modules' objects; elsewhere nothing."""
    if _own_process:
        gc.freeze()
