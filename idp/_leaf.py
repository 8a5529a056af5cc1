"""Compiled helpers without numba's reference counting: :func:`leaf_njit`.

numba keeps a reference count on every array it handles (its runtime, NRT). A compiled function counts a reference
to each of its array arguments on entry and drops it on exit, each an atomic update of the array's counter, unless
a pass proves the pair redundant, which it does not across calls to other compiled functions. The kernels here call
small helpers once per element, contact or candidate pair with up to a dozen scratch or shared arrays, and paid
that on every call: on bunny_700 (2-core Intel VM) 6.5 % of all CPU samples of a run were in numba's
``NRT_incref``/``NRT_decref``, half the time of the CCD bounds kernel and a sixth of the element pass, and an atomic
update of a counter that both threads touch (a shared input array) moves its cache line between the cores.

A helper marked ``@leaf_njit(...)`` is compiled with numba's ``_nrt=False``: no counting at all. Its array arguments
are borrowed (the caller holds them for the call), so it must neither create an array nor return one (the caller
would drop a reference it was never given). numba refuses to compile a leaf that allocates an array or returns a new
one or a view, but lets an argument through as the return value: :func:`array_returning_leaves` finds those (run on
every leaf the test suite compiles, ``tests/test_leaf.py``). Views (``X[i]``) used inside the helper are fine.
Everything else is ``numba.njit`` with ``cache=True`` and the options given.

Older ways of dodging the counts predate this and stay as they were (the same code, the same results): coordinates
passed as scalars (``intersections._orient3``), stencils read in place instead of row views, loops ended by a
condition instead of ``break`` (``_distance_kernels``, ``_elastic_kernels._rotation_svd``, ``_psd_projection``). Their
comments say what a view or a ``break`` costs in a counted function; inside a leaf neither costs anything, and a
kernel that is not a leaf (every entry point, which allocates) still pays as they describe.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from numba import njit, types

_njit: Any = njit  # ``_nrt`` is not in numba's published signature of njit

#: every dispatcher made by :func:`leaf_njit`, for :func:`array_returning_leaves`
LEAVES: list[Any] = []


def leaf_njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, _nrt=False, **options)`` for a helper that allocates no array and returns none
    (see the module docstring)."""

    def wrap(fn: Callable[..., Any]) -> Any:
        dispatcher = _njit(cache=True, _nrt=False, **options)(fn)
        LEAVES.append(dispatcher)
        return dispatcher

    return wrap


def _holds_array(t: Any) -> bool:
    if isinstance(t, types.Array):
        return True
    if isinstance(t, types.BaseTuple):
        return any(_holds_array(x) for x in getattr(t, "types", ()))
    return isinstance(t, (types.Optional,)) and _holds_array(t.type)


def array_returning_leaves() -> list[str]:
    """``module.name(signature) -> type`` of every compiled (or cache-loaded) leaf signature of this process whose
    return type holds an array: each one is a reference-count error waiting to happen."""
    bad = []
    for d in LEAVES:
        for sig in d.nopython_signatures:
            if _holds_array(sig.return_type):
                bad.append(f"{d.py_func.__module__}.{d.py_func.__name__}{sig.args} -> {sig.return_type}")
    return bad


def compiled_leaves() -> int:
    """Number of leaf signatures compiled or loaded in this process."""
    return sum(len(d.nopython_signatures) for d in LEAVES)


def load_cached_leaves() -> int:
    """Load from numba's disk cache every leaf signature that some process compiled on this machine (no code
    generation), so that :func:`array_returning_leaves` sees the leaves of callers that were themselves loaded whole
    from the cache (their leaves are then never compiled in this process). Returns the number loaded. Uses numba's
    cache index, an internal of numba: for the tests."""
    loaded = 0
    for d in LEAVES:
        cache = d._cache
        index = cache._cache_file._load_index()
        codegen = d.targetctx.codegen()
        for key in index:
            sig = key[0]
            if key == cache._index_key(sig, codegen) and sig not in d.overloads:
                d.compile(sig)
                loaded += 1
    return loaded
