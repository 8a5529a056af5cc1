"""A quicker end for idp's own processes (the CLI, the bench's scene runs).

When the interpreter shuts down it runs full garbage collections while it tears the modules down; after a run
they walk every object numba, scipy and ipctk left on the heap (about 145K), which cost 0.3–0.4 s of a 6 s
bunny_700 run on the 2-core VM (``perf``: ``gc_collect_main``, ``visit_decref`` in the last 5 % of the process).
Freezing the heap at exit moves those objects out of the collector's generations, so the shutdown
collections only see what the teardown itself frees. Atexit handlers, ``logging``'s flush and the closing of
files still run; what is skipped is collecting reference cycles that were still alive at exit (their memory goes
with the process; CPython does not promise to run their finalizers at shutdown either).
Libraries calling idp keep their own interpreter's behaviour: only the entry points of idp's processes call
:func:`freeze_heap_at_exit`.
"""

from __future__ import annotations

import atexit
import gc

_registered = False


def freeze_heap_at_exit() -> None:
    """Register ``gc.freeze`` as an exit handler, once per process. atexit runs handlers last-in first-out, so
    everything the run registers later (progress bars, writers) finishes before the freeze."""
    global _registered
    if not _registered:
        atexit.register(gc.freeze)
        _registered = True
