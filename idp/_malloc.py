"""Give freed large arrays back to the OS: a fixed glibc mmap threshold (issue 16, memory).

glibc serves an allocation of at least ``M_MMAP_THRESHOLD`` bytes with its own ``mmap`` and unmaps it on
``free``; smaller ones come from the heap, whose free space is returned to the OS only from its top. By
default the threshold is *dynamic*: every time a mapped block is freed, the threshold rises to that block's
size (up to 32 MiB). A run allocates and frees arrays of 1–30 MB every Newton iteration (the matrix values,
pattern index maps, CHOLMOD's workspace, candidate lists), so after the first few the threshold sits near
32 MiB and those arrays land in the heap, where holes between long-lived blocks (a new contact pattern's
index maps) keep them resident. Measured at bunnyx30_13K resumed at step 50 (10 steps, 2-core VM, peak RSS by GNU
time): 814 MB with the dynamic threshold, 698 MB with a fixed 1 MiB threshold, the same iterates; the high-water
mark of the factorisations alone was 813 MB dynamic and 651 / 656 / 670 / 758 MB for 256 KiB / 1 MiB / 4 MiB /
16 MiB.

Setting the threshold once (``mallopt``) also turns the dynamic adjustment off. The threshold is 4 MiB, not
1 MiB: every mapped allocation is page-faulted afresh, and at 1 MiB that cost bunny_3376 (60 steps, idle 2-core
VM) 28.3 s instead of 23.3 s (system time 6.0 s instead of 0.9 s); at 4 MiB 23.9 s, while bunnyx30_13K's late
steps peak at 616 MB instead of 610 MB (``MALLOC_MMAP_THRESHOLD_`` set to each value, same commands). Arrays
below 4 MiB (a 57K-DOF vector is 0.45 MB) stay in the heap, where reuse costs no page faults. A user's own
``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_`` or ``GLIBC_TUNABLES=glibc.malloc...`` (read by glibc at
start-up) wins: then nothing is changed. Other C libraries (musl, macOS) are left alone.

Fixing the mmap threshold also fixes glibc's *trim* threshold, at its default of 128 KiB unless set: whenever the
free space at the top of a heap exceeds it, ``free`` hands it back to the OS, and the next allocation there faults
every page in again. Arrays of a few MB (a collision set's Hessian blocks, the matrix values, the numba kernels'
scratch arrays, in the main heap and in the worker threads' arenas) are allocated and freed every Newton
iteration, so the heap top was trimmed and faulted again thousands of times a run. The trim threshold is therefore
set to 16 MiB. Measured on the 2-core Intel VM (bench children, GNU time, thresholds given through the
environment): bunny_700 minor page faults 154–178 K → 37 K and system time 0.86–1.21 → 0.48–0.74 s, wall lower in
each of eight alternating pairs (four with 256 MiB: median 7.05 → 6.69 s; four with 16 MiB: 7.50 → 6.81 s; 64 MiB
gave the same fault counts, 4 MiB kept 123 K); bunny_3376 835 K → 332 K faults, system time 3.2 → 2.4 s;
bunnyx30_13K 7.48 M → 6.22 M faults, system time 26.0 → 20.1 s, peak RSS 672.7 → 675.4 MB (64 MiB: 698.7 MB, beyond
the 1.2× of the reference's 574 MB that issue 16 allows).

Large arrays are also kept off transparent huge pages. numpy asks the kernel for huge pages on every allocation of
4 MiB or more (``madvise(MADV_HUGEPAGE)``); where the kernel's THP ``defrag`` setting is ``madvise`` (a common
default), such a page fault compacts memory on the spot when no free huge page is at hand, which it rarely is once
CHOLMOD's factors have churned the memory. Measured on the 2-core AMD EPYC VM (THP ``enabled`` and ``defrag`` both
``madvise``): a fresh 331 MB array zeroed and touched in 3.8 s with numpy's default and 0.11 s without; the stored
dumplings of Fig. 21 (399,360 DOFs), one step of 6 Newton iterations from a checkpoint, 111.2 → 81.7 s with the
same iterates, the assembly 36.0 → 9.3 s (each pattern growth allocates several such arrays). A user's own
``NUMPY_MADVISE_HUGEPAGE`` wins.
"""

from __future__ import annotations

import ctypes
import importlib
import os
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "decline_numpy_huge_pages", "fix_mmap_threshold", "is_glibc"]

#: bytes; allocations of at least this size are mapped on their own and unmapped when freed
MMAP_THRESHOLD = 4 << 20
#: bytes; free space at a heap's top is returned to the OS only beyond this
TRIM_THRESHOLD = 16 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameter numbers (malloc.h)
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def is_glibc() -> bool:
    """Whether this process runs on GNU libc (whose malloc the thresholds here are for)."""
    try:
        return bool(os.confstr("CS_GNU_LIBC_VERSION"))
    except (AttributeError, ValueError, OSError):  # not glibc (or not POSIX)
        return False


def fix_mmap_threshold(threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Set glibc's mmap threshold to ``threshold`` bytes and its trim threshold to ``trim_threshold`` bytes (both
    fixed from now on). Returns whether they were set: not on other C libraries, nor when the user configured
    glibc's malloc through the environment."""
    if not is_glibc():
        return False
    if any(name in os.environ for name in _USER_SETTINGS) or "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    try:
        libc = ctypes.CDLL(None)  # the symbols already loaded into this process: glibc's mallopt among them
        mapped = bool(libc.mallopt(ctypes.c_int(_M_MMAP_THRESHOLD), ctypes.c_int(int(threshold))))
        trimmed = bool(libc.mallopt(ctypes.c_int(_M_TRIM_THRESHOLD), ctypes.c_int(int(trim_threshold))))
        return mapped and trimmed
    except (OSError, AttributeError):
        return False


def decline_numpy_huge_pages() -> bool:
    """Stop numpy from asking for transparent huge pages for its large arrays (see the module docstring): through
    ``NUMPY_MADVISE_HUGEPAGE=0`` when numpy is not loaded yet (it reads it at import; child processes inherit it),
    else through numpy's switch. Returns whether anything was changed: not when the user set
    ``NUMPY_MADVISE_HUGEPAGE``, nor on a numpy without the switch."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return False
    os.environ["NUMPY_MADVISE_HUGEPAGE"] = "0"
    if "numpy" not in sys.modules:
        return True
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):  # numpy 2, numpy 1
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        switch = getattr(module, "_set_madvise_hugepage", None)
        if switch is not None:
            switch(False)
            return True
    return False
