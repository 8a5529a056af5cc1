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

Memory (:meth:`CholmodSolver.factor_bytes`): a supernodal factor stores every (relaxed) supernode as a dense
rows × columns block of float64. From the fundamental supernodes of the symbolic count the model is
8.4 B per block entry (CHOLMOD's relaxed amalgamation added 2–4 % zeros on the grids below) + 64 B per DOF, and
for one factorisation a workspace of the largest update block (8 B per entry) plus CHOLMOD's permuted copy of A.
Measured (bench/bench_linear.py 3D grid matrices, METIS ordering, RSS growth of ``cholmod.numeric`` read from
/proc/self/status, peak by VmHWM after resetting it): 12K DOF 48 MB (model 51), 32K DOF 197 MB (model 196),
66K DOF 489 MB (model 511). Without pymetis CHOLMOD orders inside ``cholmod.symbolic`` (AMD), the ordering is not
known beforehand and the memory guard skips the check.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

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
from idp.solver.symbolic import SymbolicCounts

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

    def __init__(self, dofs_per_node: int = 3, use_metis: bool | None = None, reuse_ordering: bool = False) -> None:
        """``use_metis``: None = if pymetis imports; ``reuse_ordering``: keep the previous
        ordering when a changed pattern has the same size (off: see the module docstring)."""
        super().__init__(dofs_per_node)
        self.use_metis = have_pymetis() if use_metis is None else bool(use_metis)
        self.reuse_ordering = bool(reuse_ordering)
        self._pattern = PatternCache()
        # bool masks, not index arrays (1 B instead of 8 B per entry: −17 MB at bunnyx30_13K): which CSR entries
        # form tril(A) (their CSR order is the CSC order of tril(A)), and which entries of the analysed pattern
        # they fill (None: all of them; the analysed pattern is a sorted superset, so the order is kept)
        self._sel: np.ndarray | None = None
        self._pos: np.ndarray | None = None
        self._S: cvxopt.spmatrix | None = None
        self._F: object | None = None
        self._perm: np.ndarray | None = None
        self._keys: np.ndarray | None = None  # sorted keys col*n + row of the analysed lower triangle
        self._factored = False
        self.union_growth = 1.3  # analyse the union of old and new patterns while it stays this small

    def _fresh(self) -> CholmodSolver:
        other = CholmodSolver(self.dofs_per_node, use_metis=self.use_metis, reuse_ordering=self.reuse_ordering)
        other.union_growth = self.union_growth
        return other

    # ------------------------------------------------------------------ pattern work
    def _analyse_lower(self, keys: np.ndarray, vals: np.ndarray, n: int) -> None:
        """Ordering + symbolic factorisation of the lower-triangle pattern given by ``keys``."""
        self._F = None
        self._pattern.clear()
        t0 = time.perf_counter()
        col, row = keys // n, keys % n
        G: sp.csr_matrix | None = None  # the full symmetric pattern, for METIS and the memory guard
        if self.reuse_ordering and self._perm is not None and self._perm.shape[0] == n:
            perm = self._perm
        elif self.use_metis:
            G = sp.csr_matrix((np.ones(keys.size), (row, col)), shape=(n, n))
            G = (G + G.T).tocsr()
            perm = nested_dissection_ordering(G.indptr, G.indices, n, self.dofs_per_node)
        else:
            perm = None
        t1 = time.perf_counter()
        if self.memory_guard is not None:  # before CHOLMOD allocates anything for this pattern
            if perm is not None and G is None:  # a reused ordering: the pattern is still needed for the count
                G = sp.csr_matrix((np.ones(keys.size), (row, col)), shape=(n, n))
                G = (G + G.T).tocsr()
            self._check_memory(None if G is None else G.indptr, None if G is None else G.indices, n, perm)
        G = None
        S = cvxopt.spmatrix(cvxopt.matrix(vals), cvxopt.matrix(row), cvxopt.matrix(col), (n, n))
        opts = {"supernodal": 2, "postorder": True, "nmethods": 1 if perm is not None else 0}
        with _options(**opts):
            if perm is not None:
                F = cholmod.symbolic(S, p=cvxopt.matrix(perm), uplo="L")
            else:
                F = cholmod.symbolic(S, uplo="L")
        t2 = time.perf_counter()
        self._S, self._F, self._perm, self._keys = S, F, perm, keys
        self.stats["ordering"] += t1 - t0
        self.stats["symbolic"] += t2 - t1
        self.stats["symbolic_analyses"] += 1

    def _load_changed_pattern(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, n: int) -> None:
        """A pattern other than the last one: reuse the symbolic factorisation when it is a subset of the
        analysed pattern (CHOLMOD then factors with explicit zeros), else analyse the union of the two
        patterns (so couplings that come and go stop triggering analyses), or the new one alone when the
        union would grow too large."""
        rowof = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        sel = indices >= rowof
        if n > 0 and np.count_nonzero(indices == rowof) != n:
            raise NotPositiveDefinite("matrix has a structurally missing diagonal entry")
        keys = rowof[sel] * n + indices[sel]
        del rowof
        vals = data[sel]
        self._sel = sel
        if self._keys is not None and self._S is not None and self._S.size[0] == n:
            pos = np.searchsorted(self._keys, keys)
            inside = pos < self._keys.size
            inside[inside] = self._keys[pos[inside]] == keys[inside]
            if inside.all():
                self._pos = self._mask(pos, self._keys.size)
                self._set_values(vals)
                self.stats["symbolic_reuses"] += 1
                self.stats["subset_reuses"] = self.stats.get("subset_reuses", 0) + 1
                return
            new = keys[~inside]  # sorted and unique, like keys
            if self._keys.size + new.size <= self.union_growth * keys.size:
                del pos, inside
                union = np.insert(self._keys, np.searchsorted(self._keys, new), new)
                self._pos = self._mask(np.searchsorted(union, keys), union.size)
                self._analyse_lower(union, self._spread(vals, union.size), n)
                return
        self._pos = None
        self._analyse_lower(keys, vals, n)

    @staticmethod
    def _mask(positions: np.ndarray, size: int) -> np.ndarray | None:
        """``positions`` (increasing) in a pattern of ``size`` entries as a bool mask; None when it is all of them."""
        if positions.size == size:
            return None
        mask = np.zeros(size, dtype=bool)
        mask[positions] = True
        return mask

    def _spread(self, vals: np.ndarray, size: int) -> np.ndarray:
        """The lower-triangle values on the analysed pattern of ``size`` entries (zeros where A has none)."""
        if self._pos is None:
            return vals
        full = np.zeros(size)
        full[self._pos] = vals
        return full

    def _set_values(self, vals: np.ndarray) -> None:
        """Copy the lower-triangle values into the analysed (possibly larger) pattern."""
        # only called once a pattern has been analysed, which sets all three
        assert self._keys is not None and self._S is not None
        self._S.V = cvxopt.matrix(self._spread(vals, self._keys.size))

    def factor_bytes(self, counts: SymbolicCounts) -> tuple[int, int]:
        """Relaxed supernodes (8.4 B per fundamental-supernode block entry, + 64 B per DOF); workspace: the largest
        update block and the permuted copy of A (see the module docstring for the measurements)."""
        factor = int(8.4 * counts.supernodal_values) + 64 * counts.n
        return factor, 8 * counts.max_update + 8 * counts.nnz_matrix + 64 * counts.n

    # ------------------------------------------------------------------ interface
    def factorize(self, A: sp.spmatrix) -> None:
        """Numeric Cholesky of ``A`` (pattern work only when the pattern changed)."""
        indptr, indices, data, n = compressed_arrays(A)
        self._check_finite_matrix(data)
        self._factored = False
        if self._pattern.same(indptr, indices) and self._S is not None:
            t0 = time.perf_counter()  # the value copy counts as numeric time
            self._set_values(data[self._sel])
            self.stats["symbolic_reuses"] += 1
        else:
            self._load_changed_pattern(indptr, indices, data, n)
            self._pattern.store(indptr, indices)
            t0 = time.perf_counter()
        self.n = n
        try:
            with _options(supernodal=2):
                cholmod.numeric(self._S, self._F)
        except ArithmeticError as exc:
            col = exc.args[0] if exc.args else "?"
            raise NotPositiveDefinite(f"CHOLMOD: matrix is not positive definite (failed at column {col})") from exc
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
