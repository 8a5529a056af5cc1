"""CHOLMOD supernodal Cholesky through cvxopt (optional, GPL-3: ``pip install idp[cholmod]``).

This module imports cvxopt at import time, so importing it fails cleanly with
ImportError when the extra is not installed; :func:`idp.solver.linear.make_linear_solver`
catches that. Nothing else in idp imports cvxopt.

Per sparsity pattern (the first call and whenever ``indptr``/``indices`` change):

1. ordering: METIS nested dissection of the vertex graph (pymetis), expanded to the
   ``dofs_per_node`` DOFs of each vertex and passed to CHOLMOD as ``p`` with
   ``nmethods=1`` (CHOLMOD's default ``nmethods=0`` would also run AMD: +0.15 s at
   59K DOF for nothing). Without pymetis CHOLMOD's AMD is used.
2. symbolic: index map of the lower triangle, one ``cvxopt.spmatrix`` built from
   triplets, ``cholmod.symbolic(S, p, uplo='L')``.

Per factorisation: the lower-triangle values are written into the existing
spmatrix (``S.V = ...``, 3 ms at 59K DOF instead of 70 ms for a new spmatrix)
and ``cholmod.numeric(S, F)`` refactors in place.

The ordering is recomputed on every pattern change by default (``reuse_ordering=False``):
on a 59K-DOF tet grid (bench/bench_linear.py), keeping the old ordering after adding
10 / 100 / 1000 contact couplings between vertices <= 3 cells apart grew nnz(L) by
6 % / 30 % / 190 % and the numeric time from 1.8-2.0 s to 2.0 / 3.1 / 11.0 s, whereas a
fresh nested dissection costs 0.13 s. Couplings between far vertices are worse still.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator

import cvxopt
import numpy as np
import scipy.sparse as sp
from cvxopt import cholmod

from idp.errors import SolverError
from idp.solver.linear import (
    LinearSolver,
    NotPositiveDefinite,
    PatternCache,
    compressed_arrays,
    have_pymetis,
    nested_dissection_ordering,
)

__all__ = ["CholmodSolver"]


@contextmanager
def _options(**values: object) -> Iterator[None]:
    """Set ``cvxopt.cholmod.options`` (a module-global dict) for one call, then restore."""
    saved = dict(cholmod.options)
    cholmod.options.update(values)
    try:
        yield
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)


class CholmodSolver(LinearSolver):
    """Supernodal CHOLMOD Cholesky (cvxopt) with METIS vertex-graph ordering and symbolic reuse."""

    name = "cholmod"

    def __init__(
        self, dofs_per_node: int = 3, use_metis: bool | None = None, reuse_ordering: bool = False
    ) -> None:
        """``use_metis``: None = if pymetis imports; ``reuse_ordering``: keep the previous
        ordering when a changed pattern has the same size (off: see the module docstring)."""
        super().__init__(dofs_per_node)
        self.use_metis = have_pymetis() if use_metis is None else bool(use_metis)
        self.reuse_ordering = bool(reuse_ordering)
        self._pattern = PatternCache()
        self._sel: np.ndarray | None = None  # entries of the CSR arrays that form tril(A) in CSC order
        self._S: cvxopt.spmatrix | None = None
        self._F: object | None = None
        self._perm: np.ndarray | None = None
        self._factored = False

    # ------------------------------------------------------------------ pattern work
    def _analyse(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, n: int) -> None:
        """Ordering, lower-triangle map, cvxopt matrix and symbolic factorisation."""
        self._F = None
        self._pattern.clear()
        t0 = time.perf_counter()
        if self.reuse_ordering and self._perm is not None and self._perm.shape[0] == n:
            perm = self._perm
        elif self.use_metis:
            perm = nested_dissection_ordering(indptr, indices, n, self.dofs_per_node)
        else:
            perm = None
        t1 = time.perf_counter()
        # Symmetric A: the CSR row r holds column r of A, so the entries with column
        # index >= r are column r of tril(A), already in CSC order (sorted rows).
        rowof = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        sel = np.flatnonzero(indices >= rowof)
        if n > 0 and np.count_nonzero(indices[sel] == rowof[sel]) != n:
            raise NotPositiveDefinite("matrix has a structurally missing diagonal entry")
        S = cvxopt.spmatrix(
            cvxopt.matrix(data[sel]),
            cvxopt.matrix(indices[sel].astype(np.int64)),
            cvxopt.matrix(rowof[sel]),
            (n, n),
        )
        opts = {"supernodal": 2, "postorder": True, "nmethods": 1 if perm is not None else 0}
        with _options(**opts):
            if perm is not None:
                F = cholmod.symbolic(S, p=cvxopt.matrix(perm), uplo="L")
            else:
                F = cholmod.symbolic(S, uplo="L")
        t2 = time.perf_counter()
        self._sel, self._S, self._F, self._perm = sel, S, F, perm
        self._pattern.store(indptr, indices)
        self.stats["ordering"] += t1 - t0
        self.stats["symbolic"] += t2 - t1
        self.stats["symbolic_analyses"] += 1

    # ------------------------------------------------------------------ interface
    def factorize(self, A: sp.spmatrix) -> None:
        """Numeric Cholesky of ``A`` (pattern work only when the pattern changed)."""
        indptr, indices, data, n = compressed_arrays(A)
        self._check_finite_matrix(data)
        self._factored = False
        if self._pattern.same(indptr, indices) and self._S is not None:
            t0 = time.perf_counter()  # the value copy counts as numeric time
            self._S.V = cvxopt.matrix(data[self._sel])
            self.stats["symbolic_reuses"] += 1
        else:
            self._analyse(indptr, indices, data, n)
            t0 = time.perf_counter()
        self.n = n
        try:
            with _options(supernodal=2):
                cholmod.numeric(self._S, self._F)
        except ArithmeticError as exc:
            col = exc.args[0] if exc.args else "?"
            raise NotPositiveDefinite(
                f"CHOLMOD: matrix is not positive definite (failed at column {col})"
            ) from exc
        finally:
            self.stats["numeric"] += time.perf_counter() - t0
        self._factored = True
        self.stats["factorizations"] += 1

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve with the current factor; ``b`` of shape (n,) or (n, k)."""
        if not self._factored:
            raise SolverError("solve() called without a successful factorize()")
        b = self._check_rhs(b)
        t0 = time.perf_counter()
        B = cvxopt.matrix(np.asfortranarray(b.reshape(self.n, -1)))
        cholmod.solve(self._F, B)
        x = np.array(B).reshape(b.shape)
        self.stats["solve"] += time.perf_counter() - t0
        if not np.isfinite(x).all():
            raise NotPositiveDefinite("CHOLMOD produced a non-finite solution")
        return x
