"""glibc's malloc settings (idp._malloc): a heap array freed and allocated again every iteration is not faulted
in afresh each time."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from idp._malloc import is_glibc

_CYCLES = 100

_SCRIPT = f"""
import json, resource
import numpy as np
import idp  # sets the thresholds unless the environment configured malloc
from idp._malloc import fix_mmap_threshold
faults = []
for _ in range({_CYCLES}):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(2 << 17)  # 2 MiB: below the mmap threshold, so from the heap; every page written
    del a
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps({{"faults": sum(faults[1:]), "fixed": fix_mmap_threshold()}}))
"""


def _run(extra_env: dict[str, str]) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    env.update(extra_env)
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_heap_top_is_kept_between_iterations():
    if not is_glibc():
        pytest.skip("not glibc: idp leaves the C library's malloc alone")
    fixed = _run({})
    # glibc's defaults for the trim threshold, with the same fixed mmap threshold (the user's setting: idp then
    # changes nothing): the 2 MiB freed at the heap's top is given back and faulted in again every cycle
    trimmed = _run({"MALLOC_MMAP_THRESHOLD_": str(4 << 20)})
    assert fixed["fixed"] and not trimmed["fixed"]
    pages = (2 << 20) // os.sysconf("SC_PAGE_SIZE")
    assert trimmed["faults"] > (_CYCLES - 1) * pages // 2, trimmed
    assert fixed["faults"] < (_CYCLES - 1) * pages // 20, fixed


_HUGE = """
{first}
import idp
import numpy
try:
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:
    from numpy.core.multiarray import _set_madvise_hugepage
print(_set_madvise_hugepage(False))
"""


@pytest.mark.parametrize("numpy_first", [False, True])
def test_numpy_large_arrays_are_kept_off_huge_pages(numpy_first):
    """numpy's madvise(MADV_HUGEPAGE) is off whether numpy loads before idp or through it; a user's own
    NUMPY_MADVISE_HUGEPAGE wins."""
    script = _HUGE.format(first="import numpy" if numpy_first else "")
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}

    def switch(extra: dict[str, str]) -> str:
        out = subprocess.run(
            [sys.executable, "-c", script], env={**env, **extra}, capture_output=True, text=True, check=True
        )
        return out.stdout.strip().splitlines()[-1]

    assert switch({}) == "False"
    assert switch({"NUMPY_MADVISE_HUGEPAGE": "1"}) == "True"
