"""CHOLMOD supernodal Cholesky through cvxopt (optional, GPL-3: ``pip install idp[cholmod]``).

This module imports cvxopt at import time, so importing it fails cleanly with
ImportError when the extra is not installed; :func:`idp.solver.linear.make_linear_solver`
catches that. Nothing else in idp imports cvxopt.

Per sparsity pattern (the first call and whenever ``indptr``/``indices`` change):

1. ordering of the vertex graph, expanded to the ``dofs_per_node`` DOFs of each vertex and
   passed to CHOLMOD as ``p`` with ``nmethods=1`` (CHOLMOD's default ``nmethods=0`` would also
   run AMD: +0.15 s at 59K DOF for nothing): METIS nested dissection (pymetis) or AMD
   (``cvxopt.amd``), whichever predicts less factorisation work (:func:`choose_ordering`). Without
   pymetis CHOLMOD's AMD is used.
2. symbolic: the upper triangle's columns merged with the analysed ones (compiled merge walks,
   :mod:`idp.solver.triangle_pattern`: at the Fig. 12 cat 35 → 6 ms per changed pattern, and the
   vertex graph 19 → 3 ms), one ``cvxopt.spmatrix`` built from triplets (for a pattern grown
   from the analysed one: that matrix plus explicit zeros at the new entries),
   ``cholmod.symbolic(S, p, uplo='U')``.

Per factorisation: the upper-triangle values are written into the existing
spmatrix (``S.V = ...``, 3 ms at 59K DOF instead of 70 ms for a new spmatrix)
and ``cholmod.numeric(S, F)`` refactors in place.

Why the upper triangle: ``cholmod.numeric`` hands CHOLMOD a packed copy of the stored triangle, and CHOLMOD's
supernodal factorisation wants tril(PAPᵀ): from an upper triangle that is one permuted transpose, from a lower one
two (triu(PAPᵀ), then its transpose), all three copies alive at once. At bunnyx30_13K's late Newton matrices
(1.25 M stored entries, 57K DOFs) the transient growth of a factorisation is 57.1 MB with the lower triangle and
47.9 MB with the upper (the rest is the largest update block), the same factor (RSS around ``cholmod.numeric``
after resetting VmHWM, the run's peak being one of these factorisations).

The ordering is recomputed on every pattern change by default (``reuse_ordering=False``):
on a 59K-DOF tet grid (bench/bench_linear.py), keeping the old ordering after adding
10 / 100 / 1000 contact couplings between vertices <= 3 cells apart grew nnz(L) by
6 % / 30 % / 190 % and the numeric time from 1.8-2.0 s to 2.0 / 3.1 / 11.0 s, whereas a
fresh nested dissection costs 0.13 s. Couplings between far vertices are worse still.

Which ordering: on volumes METIS needs far less work (bunny_3376's Newton matrices: AMD's factorisation 1.2–1.7× as
slow), on surfaces the two are alike (the Fig. 12 cat: the same numeric time) while AMD orders 3–5× faster (cat
5 against 22–26 ms, Kick 7–13 against 28–56 ms). Both are computed at the first analysis and again after
``ORDERING_RECHECK`` analyses, an interval that doubles while the choice stays the same, and the one with fewer
predicted flops (Σ c_j² of the vertex graph's factor column counts, within ``AMD_MARGIN``) is used until the next
comparison.

Memory (:meth:`CholmodSolver.factor_bytes`): a supernodal factor stores every (relaxed) supernode as a dense
rows × columns block of float64. From the fundamental supernodes of the symbolic count the model is
8.4 B per block entry (CHOLMOD's relaxed amalgamation added 2–4 % zeros on the grids below) + 64 B per DOF, and
for one factorisation a workspace of the largest update block (8 B per entry) plus cvxopt's packed copy of the stored
triangle and CHOLMOD's permuted one (16 B per entry each: long indices).
Measured (bench/bench_linear.py 3D grid matrices, METIS ordering, RSS growth of ``cholmod.numeric`` read from
/proc/self/status, peak by VmHWM after resetting it): 12K DOF 48 MB (model 51), 32K DOF 197 MB (model 196),
66K DOF 489 MB (model 511) — measured while CHOLMOD was given the lower triangle, before 2026-11-28; the model's
workspace now counts the two copies of the triangle it holds given the upper one (the step estimates against whole
runs: :mod:`idp.solver.memory`). Without pymetis CHOLMOD orders inside ``cholmod.symbolic`` (AMD), the ordering is not
known beforehand and the memory guard skips the check.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager

import cvxopt
import numba
import numpy as np
import scipy.sparse as sp
from cvxopt import amd, cholmod

from idp.errors import SolverError
from idp.solver.cholmod_blas import cholmod_threads, route_cholmod_blas, worth_threads
from idp.solver.linear import (
    LinearSolver,
    NotPositiveDefinite,
    PatternCache,
    compressed_arrays,
    expand_vertex_ordering,
    have_pymetis,
    metis_vertex_ordering,
    nested_dissection_ordering,
)
from idp.solver.symbolic import SymbolicCounts, cholesky_flops
from idp.solver.triangle_pattern import (
    locate_entries,
    symmetric_from_triangle,
    union_columns,
    upper_columns,
    vertex_graph_from_triangle,
)

__all__ = ["CholmodSolver", "choose_ordering"]

#: AMD is used while its predicted factorisation work is at most this multiple of METIS's (it orders faster)
AMD_MARGIN = 1.03
#: analyses between the first two comparisons of the orderings (the chosen one alone is computed in between); the
#: interval doubles each time a comparison confirms the choice and comes back to this when the choice changes
ORDERING_RECHECK = 4


def amd_vertex_ordering(xadj: np.ndarray, adjncy: np.ndarray) -> np.ndarray:
    """Approximate minimum degree (SuiteSparse AMD through ``cvxopt.amd``) of a graph: the vertex order, int64."""
    nv = xadj.size - 1
    rows = np.repeat(np.arange(nv, dtype=np.int64), np.diff(xadj))
    keep = adjncy > rows  # AMD reads one triangle (the lower one: row > column)
    G = cvxopt.spmatrix(1.0, cvxopt.matrix(adjncy[keep]), cvxopt.matrix(rows[keep]), (nv, nv))
    return np.array(amd.order(G, uplo="L"), dtype=np.int64).ravel()


def choose_ordering(xadj: np.ndarray, adjncy: np.ndarray) -> tuple[str, np.ndarray]:
    """("metis" or "amd", vertex order): METIS nested dissection and AMD of the vertex graph, and the one whose factor
    needs fewer flops (AMD when within ``AMD_MARGIN`` of METIS, as it orders faster)."""
    nv = xadj.size - 1
    metis, approx = metis_vertex_ordering(xadj, adjncy), amd_vertex_ordering(xadj, adjncy)
    # int32 indices, as the Newton matrices' own patterns are counted (one compiled specialisation of the counts)
    ptr, idx = (a.astype(np.int32) for a in (xadj, adjncy)) if adjncy.size < 2**31 else (xadj, adjncy)
    f_metis = cholesky_flops(ptr, idx, nv, metis)
    f_amd = cholesky_flops(ptr, idx, nv, approx)
    return ("amd", approx) if f_amd <= AMD_MARGIN * f_metis else ("metis", metis)


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


#: Without a memory guard's symbolic counts, factors of at least this many unknowns run CHOLMOD's calls threaded.
THREADED_MIN_DOFS = 40_000


def _pattern_fingerprint(aptr: np.ndarray, arow: np.ndarray, n: int) -> np.ndarray:
    """(n, stored entries, CRC-32 of the column pointers, CRC-32 of the rows) of an upper-triangle pattern."""
    ptr = np.ascontiguousarray(aptr, dtype=np.int64)
    row = np.ascontiguousarray(arow, dtype=np.int32)
    return np.array([n, row.size, zlib.crc32(ptr.tobytes()), zlib.crc32(row.tobytes())], dtype=np.int64)


def _restorable(restore: tuple[np.ndarray, np.ndarray], aptr: np.ndarray, arow: np.ndarray, n: int, ordered: bool):
    """Whether a checkpoint's (fingerprint, ordering) is that of this pattern, the ordering a permutation of its
    n DOFs (empty: CHOLMOD's own, when idp does not order)."""
    fingerprint, perm = restore
    if not np.array_equal(fingerprint, _pattern_fingerprint(aptr, arow, n)):
        return False
    if not ordered:
        return perm.size == 0
    return perm.size == n and np.array_equal(np.sort(perm), np.arange(n))


class CholmodSolver(LinearSolver):
    """Supernodal CHOLMOD Cholesky (cvxopt) with METIS vertex-graph ordering and symbolic reuse."""

    name = "cholmod"

    def __init__(self, dofs_per_node: int = 3, use_metis: bool | None = None, reuse_ordering: bool = False) -> None:
        """``use_metis``: None = if pymetis imports; ``reuse_ordering``: keep the previous
        ordering when a changed pattern has the same size (off: see the module docstring)."""
        super().__init__(dofs_per_node)
        route_cholmod_blas(numba.get_num_threads())  # CHOLMOD's dense kernels on scipy's threaded OpenBLAS
        self.use_metis = have_pymetis() if use_metis is None else bool(use_metis)
        self.reuse_ordering = bool(reuse_ordering)
        self._pattern = PatternCache()
        # bool masks, not index arrays (1 B instead of 8 B per entry: −17 MB at bunnyx30_13K): which CSR entries
        # form triu(A) (their CSR order is the CSC order of triu(A)), and which entries of the analysed pattern
        # they fill (None: all of them; the analysed pattern is a sorted superset, so the order is kept)
        self._sel: np.ndarray | None = None
        self._pos: np.ndarray | None = None
        self._S: cvxopt.spmatrix | None = None
        self._F: object | None = None
        self._perm: np.ndarray | None = None
        # the analysed upper triangle's columns: pointers (int64) and sorted rows (int32)
        self._aptr: np.ndarray | None = None
        self._arow: np.ndarray | None = None
        self._factored = False
        self._threaded = False  # CHOLMOD's calls on the threaded BLAS pool (large factors only)
        self.union_growth = 1.3  # analyse the union of old and new patterns while it stays this small
        self._ordering_kind: str | None = None  # "metis" or "amd": the last comparison's choice
        self._since_ordering_check = 0  # analyses since that comparison
        self._ordering_interval = ORDERING_RECHECK  # analyses until the next one
        self._restore: tuple[np.ndarray, np.ndarray] | None = None  # a checkpoint's analysis (load_state)

    def _fresh(self) -> CholmodSolver:
        other = CholmodSolver(self.dofs_per_node, use_metis=self.use_metis, reuse_ordering=self.reuse_ordering)
        other.union_growth = self.union_growth
        return other

    # ------------------------------------------------------------------ pattern work
    def _analyse(
        self, aptr: np.ndarray, arow: np.ndarray, vals: np.ndarray, n: int, S: cvxopt.spmatrix | None = None
    ) -> None:
        """Ordering + symbolic factorisation of the upper-triangle pattern with columns (aptr, arow); ``S``: that
        pattern's matrix (holding ``vals``) when the caller has it, else it is built here."""
        self._F, self._S = None, None  # the last pattern's factor and matrix: freed before this one's are built
        self._pattern.clear()
        t0 = time.perf_counter()
        restore, self._restore = self._restore, None
        if restore is not None and _restorable(restore, aptr, arow, n, self.use_metis):
            perm = restore[1] if restore[1].size else None  # the pattern the run had analysed: its ordering
        elif self.reuse_ordering and self._perm is not None and self._perm.shape[0] == n:
            perm = self._perm
        elif self.use_metis:
            perm = self._ordering(aptr, arow, n)
        else:
            perm = None
        t1 = time.perf_counter()
        if self.memory_guard is not None:  # before CHOLMOD allocates anything for this pattern
            full = symmetric_from_triangle(aptr, arow) if perm is not None else (None, None)
            self._check_memory(full[0], full[1], n, perm)
            del full
        # threaded BLAS only for factors with large dense blocks (see idp.solver.cholmod_blas.worth_threads)
        last = None if self.memory_guard is None or perm is None else self.memory_guard.last
        self._threaded = worth_threads(last.counts.max_update) if last is not None else n >= THREADED_MIN_DOFS
        if S is None:
            col = np.repeat(np.arange(n, dtype=np.int64), np.diff(aptr))
            S = cvxopt.spmatrix(cvxopt.matrix(vals), cvxopt.matrix(arow.astype(np.int64)), cvxopt.matrix(col), (n, n))
            del col
        opts = {"supernodal": 2, "postorder": True, "nmethods": 1 if perm is not None else 0}
        with _options(**opts):
            if perm is not None:
                F = cholmod.symbolic(S, p=cvxopt.matrix(perm), uplo="U")
            else:
                F = cholmod.symbolic(S, uplo="U")
        t2 = time.perf_counter()
        self._S, self._F, self._perm, self._aptr, self._arow = S, F, perm, aptr, arow
        self.stats["ordering"] += t1 - t0
        self.stats["symbolic"] += t2 - t1
        self.stats["symbolic_analyses"] += 1

    def _own_state(self) -> dict[str, np.ndarray]:
        """The ordering schedule (the last comparison's choice, analyses since it, the interval to the next) and
        the analysed pattern's fingerprint and ordering: a resumed run that first meets that same pattern takes
        that ordering without counting an analysis, as the uninterrupted run, which had it analysed, factorises
        on it without one; so both then make the same choices, and the same factors."""
        kind = {None: -1, "metis": 0, "amd": 1}[self._ordering_kind]
        st = {"schedule": np.array([kind, self._since_ordering_check, self._ordering_interval], dtype=np.int64)}
        if self._aptr is not None and self._arow is not None:
            st["fingerprint"] = _pattern_fingerprint(self._aptr, self._arow, self._aptr.size - 1)
            st["perm"] = np.zeros(0, np.int64) if self._perm is None else np.asarray(self._perm, dtype=np.int64)
        return st

    def _load_own_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`_own_state`. Only an optimisation for identical resumed runs: values that are missing (a
        checkpoint written before they were kept) or not as :meth:`state` writes them are ignored, and the solver
        then chooses afresh."""

        def integers(key: str, shape: tuple[int, ...] | None) -> np.ndarray | None:
            a = np.asarray(state.get(key, np.zeros(0, np.int64)))
            ok = a.dtype.kind in "iu" and a.ndim == 1 and (shape is None or a.shape == shape)
            return a.astype(np.int64) if ok else None

        schedule = integers("schedule", (3,))
        if schedule is None:
            return
        kind, since, interval = (int(v) for v in schedule)
        self._ordering_kind = {0: "metis", 1: "amd"}.get(kind)
        self._since_ordering_check, self._ordering_interval = max(0, since), max(1, interval)
        fingerprint, perm = integers("fingerprint", (4,)), integers("perm", None)
        if fingerprint is not None and perm is not None:
            self._restore = (fingerprint, perm)

    def _ordering(self, aptr: np.ndarray, arow: np.ndarray, n: int) -> np.ndarray:
        """Fill-reducing DOF ordering of the symmetric pattern with upper-triangle columns (aptr, arow): METIS or
        AMD of its vertex graph, compared from time to time (:func:`choose_ordering`; see the module docstring),
        the last choice alone in between."""
        d = self.dofs_per_node
        if n == 0 or n % d:
            indptr, indices = symmetric_from_triangle(aptr, arow)
            return nested_dissection_ordering(indptr, indices, n, d)
        xadj, adjncy = vertex_graph_from_triangle(aptr, arow, int(d))
        if self._ordering_kind is None or self._since_ordering_check >= self._ordering_interval:
            previous = self._ordering_kind
            self._ordering_kind, vperm = choose_ordering(xadj, adjncy)
            same = previous == self._ordering_kind
            self._ordering_interval = 2 * self._ordering_interval if same else ORDERING_RECHECK
            self._since_ordering_check = 1
            self.stats["ordering_checks"] = self.stats.get("ordering_checks", 0) + 1
        else:
            self._since_ordering_check += 1
            order = metis_vertex_ordering if self._ordering_kind == "metis" else amd_vertex_ordering
            vperm = order(xadj, adjncy)
        key = f"{self._ordering_kind}_orderings"
        self.stats[key] = self.stats.get(key, 0) + 1
        return expand_vertex_ordering(vperm, d)

    def _load_changed_pattern(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, n: int) -> None:
        """A pattern other than the last one: reuse the symbolic factorisation when it is a subset of the
        analysed pattern (CHOLMOD then factors with explicit zeros), else analyse the union of the two
        patterns (so couplings that come and go stop triggering analyses), or the new one alone when the
        union would grow too large. (Merge walks over sorted columns: :mod:`idp.solver.triangle_pattern`.)"""
        rows = indices.view() if indices.dtype == np.int32 else indices.astype(np.int32)
        rows.flags.writeable = False  # read-only like the contact pattern's own: one compiled specialisation
        cptr, sel, diagonal = upper_columns(np.array(indptr, dtype=np.int64), rows)
        if n > 0 and not diagonal:
            raise NotPositiveDefinite("matrix has a structurally missing diagonal entry")
        crow, vals = rows[sel], data[sel]
        del rows
        self._sel = sel
        aptr, arow = self._aptr, self._arow
        if aptr is not None and arow is not None and self._S is not None and self._S.size[0] == n:
            found = np.zeros(arow.size, dtype=bool)
            n_new = locate_entries(cptr, crow, aptr, arow, found)
            if n_new == 0:
                self._pos = None if crow.size == arow.size else found
                self._set_values(vals)
                self.stats["symbolic_reuses"] += 1
                self.stats["subset_reuses"] = self.stats.get("subset_reuses", 0) + 1
                return
            # a new analysis follows: free the old factor before the union is built (bunnyx30_13K with the contact
            # look-ahead: the run's peak memory was reached building the union with the last factor still alive)
            self._F = None
            if arow.size + n_new <= self.union_growth * crow.size:
                del found
                union_ptr, union_row, mask, new_rows, new_cols = union_columns(cptr, crow, aptr, arow, n_new)
                self._pos = None if union_row.size == crow.size else mask
                del mask
                full = self._spread(vals, union_row.size)
                # the analysed matrix plus explicit zeros at the new entries: cvxopt merges the sorted columns, a
                # third of the time of building the union from triplets (5 against 14 ms at the Fig. 12 cat)
                S = self._S + cvxopt.spmatrix(0.0, cvxopt.matrix(new_rows), cvxopt.matrix(new_cols), (n, n))
                self._S = None  # the old matrix: not alive during the ordering and the symbolic analysis
                if len(S) == union_row.size:
                    S.V = cvxopt.matrix(full)
                else:  # (cvxopt dropped or merged an entry: never seen) the union from its columns
                    S = None
                self._analyse(union_ptr, union_row, full, n, S)
                return
        self._pos = None
        self._analyse(cptr, crow, vals, n)

    def _spread(self, vals: np.ndarray, size: int) -> np.ndarray:
        """The upper-triangle values on the analysed pattern of ``size`` entries (zeros where A has none)."""
        if self._pos is None:
            return vals
        full = np.zeros(size)
        full[self._pos] = vals
        return full

    def _set_values(self, vals: np.ndarray) -> None:
        """Copy the upper-triangle values into the analysed (possibly larger) pattern."""
        # only called once a pattern has been analysed, which sets all three
        assert self._arow is not None and self._S is not None
        self._S.V = cvxopt.matrix(self._spread(vals, self._arow.size))

    def factor_bytes(self, counts: SymbolicCounts) -> tuple[int, int]:
        """Relaxed supernodes (8.4 B per fundamental-supernode block entry, + 64 B per DOF); workspace: the largest
        update block and two copies of the stored triangle, 16 B per entry each (cvxopt's packed one and CHOLMOD's
        permuted one; about half of ``nnz_matrix`` each: see the module docstring for the measurements)."""
        factor = int(8.4 * counts.supernodal_values) + 64 * counts.n
        return factor, 8 * counts.max_update + 16 * counts.nnz_matrix + 64 * counts.n

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
            with _options(supernodal=2), cholmod_threads(self._threaded):
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
        with cholmod_threads(self._threaded):
            cholmod.solve(self._F, B)
        x = np.array(B).reshape(b.shape)
        self.stats["solve"] += time.perf_counter() - t0
        if not np.isfinite(x).all():
            raise NotPositiveDefinite("CHOLMOD produced a non-finite solution")
        return x
