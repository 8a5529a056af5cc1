"""numpy's and scipy's OpenBLAS kept to one thread while a run steps.

idp's parallel work is numba's OpenMP (element kernels) and ipctk's TBB (contact, CCD); the BLAS calls numpy and
scipy make inside the loop are small vector operations. An OpenBLAS pool with more than one thread keeps its
workers spinning after each call, taking the cores the next numba or TBB region needs. ``idp/__init__`` sets
``OPENBLAS_THREAD_TIMEOUT`` for that, but OpenBLAS reads it only when it loads, so it has no effect when numpy is
imported before idp — the usual order in user code and in every test. Measured on the 2-core AMD EPYC, the Fig. 10
bar, 4 steps, `import numpy` first: element assembly 29.6 → 17.5 ms per Newton iteration, CCD 6.5 → 4.6 ms, with
this limit (the same as importing idp first). CHOLMOD's calls, routed to scipy's OpenBLAS
(:mod:`idp.solver.cholmod_blas`), widen scipy's pool again for their own duration where the factor is large.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from threadpoolctl import ThreadpoolController

_CONTROLLED = ("numpy", "scipy")  # the OpenBLAS copies bundled with these wheels (file paths name the package)


@contextmanager
def quiet_blas() -> Iterator[None]:
    """Within the block, numpy's and scipy's BLAS pools run one thread; their previous sizes are restored after."""
    controller = ThreadpoolController()
    libs = [
        lib
        for lib in controller.lib_controllers
        if lib.user_api == "blas" and any(name in lib.filepath for name in _CONTROLLED) and lib.num_threads > 1
    ]
    before = [lib.num_threads for lib in libs]
    for lib in libs:
        lib.set_num_threads(1)
    try:
        yield
    finally:
        for lib, n in zip(libs, before, strict=True):
            lib.set_num_threads(n)
