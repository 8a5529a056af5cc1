"""``--threads`` in a process whose numba pool has already started (a script, a test, a second ``main`` call)."""

from __future__ import annotations

import os
import subprocess
import sys

SCRIPT = r"""
import os
import numba
import numpy as np

@numba.njit(parallel=True)
def total(a):
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s

total(np.ones(8))  # the pool starts with NUMBA_NUM_THREADS = 2 (set below by the parent)
from idp.cli import _set_threads
_set_threads(3)  # a different count, after the pool started

@numba.njit
def later(x):  # compiled after --threads: numba re-reads NUMBA_NUM_THREADS here
    return x + 1

assert later(1) == 2
assert numba.get_num_threads() == 2  # at most the pool's size
assert os.environ["OMP_NUM_THREADS"] == "3"
print("ok")
"""


def test_threads_after_numba_started_leave_later_compiles_working():
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]


SCRIPT_IMPORTED = r"""
import numba
import numpy as np
from idp.cli import _set_threads

_set_threads(1)  # numba imported (it read NUMBA_NUM_THREADS = 2 then), its pool not started

@numba.njit(parallel=True)
def total(a):  # compiled after --threads 1 (a cold kernel cache): numba re-reads NUMBA_NUM_THREADS here
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s

assert total(np.ones(8)) == 8.0
assert numba.config.NUMBA_NUM_THREADS == 1 and numba.get_num_threads() == 1
print("ok")
"""


def test_threads_after_numba_imported_start_the_pool_at_that_size():
    """``idp run --threads 1`` on a cold kernel cache, a 2-core machine: the pool used to start at numba's
    import-time size (2) and the first kernel compiled failed on NUMBA_NUM_THREADS = 1."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT_IMPORTED], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]
