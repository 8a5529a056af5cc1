"""Sparse SPD linear solvers for the projected-Newton systems.

Every Newton iteration factorises a symmetric positive definite matrix ``A`` (free
DOFs only, ``dofs_per_node`` interleaved DOFs per vertex) and solves one system.
The sparsity pattern usually repeats between iterations, so each backend keeps its
pattern-dependent work (ordering, symbolic analysis, index maps) and redoes it only
when ``A.indptr`` / ``A.indices`` change (e.g. when contacts appear or vanish).

Backends
--------
``"cholmod"``
    Supernodal Cholesky of CHOLMOD through cvxopt (GPL-3, optional extra
    ``pip install idp[cholmod]``), ordered by METIS nested dissection of the vertex
    graph. See :mod:`idp.solver.cholmod_cvxopt`.
``"scipy"``
    Always available. SuperLU (``scipy.sparse.linalg.splu``) in symmetric mode without
    pivoting (``diag_pivot_thresh=0``): for SPD matrices the diagonal pivots are the
    Cholesky pivots, so this is a (2x memory) Cholesky in disguise. If pymetis is
    importable the same vertex-graph nested-dissection ordering is used (reused while
    the pattern is unchanged), otherwise SuperLU's ``MMD_AT_PLUS_A``. Measured on the
    3D tet-grid block matrices of bench/bench_linear.py (2 cores, shared), factor + solve
    at 20K DOF: splu+ND 1.4 s, splu+MMD 2.2 s, splu COLAMD 3.5 s, ``spsolve`` 3.4 s; at
    59K DOF: splu+ND 11 s, splu+MMD 42 s, ``spsolve`` 62 s (CHOLMOD: 2.0 s). Jacobi-CG
    (rtol 1e-11) took 0.06 s on the easy mass-dominated matrix but 2.4 s / 4,657
    iterations on a heterogeneous one (edge stiffness 10^+-3, anisotropy 1e3) and then
    stalled at a true residual of 2e-10; barrier Hessians are far worse conditioned. A
    direct solver is the robust choice for the fallback.

``make_linear_solver("auto")`` picks CHOLMOD when cvxopt imports, else scipy.
"""

from __future__ import annotations

import re
import time
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from idp.errors import SolverError

if TYPE_CHECKING:
    from idp.solver.memory import MemoryEstimate, MemoryGuard
    from idp.solver.symbolic import SymbolicCounts

__all__ = [
    "LinearSolver",
    "NotPositiveDefinite",
    "ScipySolver",
    "available_solvers",
    "have_pymetis",
    "make_linear_solver",
    "nested_dissection_ordering",
]

_BACKENDS: tuple[str, ...] = ("cholmod", "scipy")
_CHOICES: tuple[str, ...] = ("auto", *_BACKENDS)


class NotPositiveDefinite(SolverError):
    """The matrix is not (numerically) symmetric positive definite."""


# --------------------------------------------------------------------------- helpers


_SIBLING_KEY = re.compile(r"sibling(\d+)__(.+)")


def _new_stats() -> dict[str, float]:
    return {
        "ordering": 0.0,
        "symbolic": 0.0,
        "numeric": 0.0,
        "solve": 0.0,
        "factorizations": 0,
        "symbolic_reuses": 0,
        "symbolic_analyses": 0,
    }


def compressed_arrays(A: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Return ``(indptr, indices, data, n)`` of a square symmetric sparse matrix.

    CSR arrays are returned as they are; CSC arrays of a symmetric matrix are the CSR
    arrays of its transpose, i.e. of the same matrix, so they are returned unchanged
    too. Other formats are converted to CSR. Arrays are copied (and sorted, summed)
    only when the input is not in canonical form. ``data`` is float64.
    """
    if not sp.issparse(A):
        raise TypeError(f"expected a scipy.sparse matrix, got {type(A).__name__}")
    if A.format not in ("csr", "csc"):
        A = A.tocsr()
    n, m = A.shape
    if n != m:
        raise ValueError(f"matrix must be square, got shape {A.shape}")
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    data = A.data
    if data.dtype != np.float64:
        data = data.astype(np.float64)
    return A.indptr, A.indices, data, int(n)


def _frozen(a: np.ndarray) -> bool:
    """Read-only, and so is the array owning its memory: no view of it can write (numpy makes no writeable view
    of a read-only array) unless the owner sets itself writeable again, which the one owner that freezes its
    arrays (:class:`idp.solver.assembly.BlockLayout`) never does. scipy's matrices hold views of those arrays."""
    owner = a
    while isinstance(owner.base, np.ndarray):
        owner = owner.base
    return not a.flags.writeable and owner.base is None and not owner.flags.writeable


def _same_memory(a: np.ndarray, b: np.ndarray) -> bool:
    """The same elements of the same memory (so equal, when that memory is frozen)."""
    return (
        a.__array_interface__["data"][0] == b.__array_interface__["data"][0]
        and a.dtype == b.dtype
        and a.shape == b.shape
        and a.strides == b.strides
    )


class PatternCache:
    """Remember one sparsity pattern and compare new ones against it cheaply."""

    def __init__(self) -> None:
        self.indptr: np.ndarray | None = None
        self.indices: np.ndarray | None = None

    def same(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        """True when ``(indptr, indices)`` equals the stored pattern (O(nnz) memcmp)."""
        if self.indptr is None or self.indices is None:
            return False
        if self.indptr.shape != indptr.shape or self.indices.shape != indices.shape:
            return False
        frozen = _frozen(self.indptr) and _frozen(self.indices) and _frozen(indptr) and _frozen(indices)
        if frozen and _same_memory(self.indptr, indptr) and _same_memory(self.indices, indices):
            return True
        return bool(np.array_equal(self.indptr, indptr) and np.array_equal(self.indices, indices))

    def store(self, indptr: np.ndarray, indices: np.ndarray) -> None:
        """Keep private copies (the caller may reuse its arrays in place), or the arrays themselves when nobody can
        change them: read-only arrays that own their memory (the contact pattern's layouts; at bunnyx30_13K the
        copies were 9.7 MB)."""
        self.indptr = indptr if _frozen(indptr) else np.array(indptr, copy=True)
        self.indices = indices if _frozen(indices) else np.array(indices, copy=True)

    def clear(self) -> None:
        self.indptr = None
        self.indices = None


def have_pymetis() -> bool:
    """Whether pymetis (MIT, METIS nested dissection) can be imported."""
    try:
        import pymetis  # noqa: F401
    except ImportError:
        return False
    return True


def vertex_graph(indptr: np.ndarray, indices: np.ndarray, n: int, dofs_per_node: int) -> tuple[np.ndarray, np.ndarray]:
    """Adjacency ``(xadj, adjncy)`` of the vertex graph of a symmetric DOF pattern.

    Vertex ``v`` owns DOFs ``d*v .. d*v+d-1``; two vertices are adjacent when any of
    their DOFs couple. Self loops are removed (METIS requires that).
    """
    d = dofs_per_node
    nv = n // d
    # The rows of vertex v are contiguous, so indptr[::d] is a valid (duplicate-laden)
    # CSR row pointer of the vertex graph; sum_duplicates dedupes in C++.
    G = sp.csr_matrix(
        (np.ones(indices.shape[0], dtype=np.int32), indices // d, np.array(indptr[::d], copy=True)),
        shape=(nv, nv),
    )
    G.sum_duplicates()
    rows = np.repeat(np.arange(nv, dtype=np.int64), np.diff(G.indptr))
    keep = G.indices != rows
    adjncy = G.indices[keep].astype(np.int64)
    xadj = np.zeros(nv + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows[keep], minlength=nv), out=xadj[1:])
    return xadj, adjncy


def metis_vertex_ordering(xadj: np.ndarray, adjncy: np.ndarray) -> np.ndarray:
    """METIS nested dissection (pymetis) of a graph without self loops: the vertex order, int64."""
    import pymetis

    if hasattr(pymetis, "CSRAdjacency"):
        perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(xadj, adjncy))
    else:  # pymetis < 2025.2
        perm, _ = pymetis.nested_dissection(xadj=xadj, adjncy=adjncy)
    # pymetis returns array('q'); np.asarray of it may come out unsigned, so cast.
    return np.array(perm, dtype=np.int64)


def expand_vertex_ordering(vperm: np.ndarray, dofs_per_node: int) -> np.ndarray:
    """The DOF permutation that orders vertices by ``vperm`` and keeps each vertex's DOFs together, in order."""
    d = int(dofs_per_node)
    if d == 1:
        return np.asarray(vperm, dtype=np.int64)
    return (d * np.asarray(vperm, dtype=np.int64)[:, None] + np.arange(d, dtype=np.int64)).ravel()


def nested_dissection_ordering(indptr: np.ndarray, indices: np.ndarray, n: int, dofs_per_node: int) -> np.ndarray:
    """Fill-reducing DOF permutation from METIS nested dissection of the vertex graph.

    Returns ``p`` (int64, length n) with the meaning of CHOLMOD's ``p``: the factorised
    matrix is ``A[p][:, p]``. The vertex ordering is expanded to the DOFs of each vertex
    (kept together). If ``n`` is not a multiple of ``dofs_per_node`` the scalar graph is
    ordered instead. Needs pymetis.
    """
    d = dofs_per_node if (dofs_per_node >= 1 and n % dofs_per_node == 0) else 1
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    xadj, adjncy = vertex_graph(indptr, indices, n, d)
    return expand_vertex_ordering(metis_vertex_ordering(xadj, adjncy), d)


# --------------------------------------------------------------------------- interface


class LinearSolver(ABC):
    """Factorise-then-solve interface for sparse SPD systems.

    ``factorize`` takes the full symmetric matrix (both triangles, CSR or CSC) and
    reuses the pattern-dependent work when ``indptr``/``indices`` equal the previous
    call's. ``stats`` accumulates seconds (``ordering``, ``symbolic``, ``numeric``,
    ``solve``) and counts (``factorizations``, ``symbolic_reuses``,
    ``symbolic_analyses``).

    ``memory_guard`` (an :class:`idp.solver.memory.MemoryGuard`, set by the Newton solver): called by the backend
    with every new pattern and the ordering it will factorise it in, before its symbolic and numeric
    factorisations; it raises :class:`idp.errors.ResourceError` when the step would not fit in memory.
    """

    name: str = "abstract"
    # bytes per stored entry of the (full, both-triangle) Hessian pattern for the matrix itself (CSR, 8 + 4), the
    # backend's copy of one triangle (8) and the index maps the assembly keeps of it (checked with the other parts
    # against measured runs, see idp.solver.memory)
    hessian_bytes_per_entry: int = 32

    def __init__(self, dofs_per_node: int = 3) -> None:
        if int(dofs_per_node) < 1:
            raise ValueError(f"dofs_per_node must be >= 1, got {dofs_per_node}")
        self.dofs_per_node = int(dofs_per_node)
        self.stats: dict[str, float] = _new_stats()
        self.n: int = 0
        self.memory_guard: MemoryGuard | None = None
        self._siblings: list[LinearSolver] = []  # made by sibling(), in order: their state is kept with this one's
        self._sibling_states: dict[int, dict[str, np.ndarray]] = {}  # a checkpoint's, for siblings not yet made

    def _check_memory(
        self, indptr: np.ndarray | None, indices: np.ndarray | None, n: int, perm: np.ndarray | None
    ) -> None:
        """Hand a new pattern (CSR/CSC arrays holding both triangles) and the ordering it will be factorised in to
        the memory guard, if there is one (``perm`` None: the backend orders inside its factorisation)."""
        if self.memory_guard is not None:
            self.memory_guard.check(self, indptr, indices, n, perm)

    def factor_bytes(self, counts: SymbolicCounts) -> tuple[int, int]:
        """(bytes of the stored factor, transient workspace bytes of one factorisation) for this backend.

        Default: a simplicial Cholesky, 12 B per nonzero of L (value + row index) and a copy of A."""
        return 12 * counts.nnz_factor + 16 * counts.n, 12 * counts.nnz_matrix

    def memory_estimate(self, counts: SymbolicCounts, other_bytes: int = 0) -> MemoryEstimate:
        """The step's estimated peak memory for a pattern with these symbolic counts (see :mod:`idp.solver.memory`)."""
        from idp.solver.memory import SAFETY_MARGIN, MemoryEstimate

        factor, workspace = self.factor_bytes(counts)
        hessian = self.hessian_bytes_per_entry * counts.nnz_matrix + 16 * counts.n
        return MemoryEstimate(
            backend=self.name,
            counts=counts,
            factor_bytes=int(factor),
            workspace_bytes=int(workspace),
            hessian_bytes=int(hessian),
            other_bytes=int(other_bytes),
            margin_bytes=int(SAFETY_MARGIN * (factor + workspace + hessian + other_bytes)),
        )

    @abstractmethod
    def factorize(self, A: sp.spmatrix) -> None:
        """Factorise the symmetric matrix ``A``; raise :class:`NotPositiveDefinite` on failure."""

    @abstractmethod
    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` with the last factorisation (``b`` of shape (n,) or (n, k))."""

    def reset_stats(self) -> None:
        """Zero the timing and count statistics (in place: siblings count into the same dictionary)."""
        self.stats.clear()
        self.stats.update(_new_stats())

    def state(self) -> dict[str, np.ndarray]:
        """What a run's checkpoint keeps of this solver so that a resumed run factorises as the uninterrupted one
        would: the backend's own history-dependent choices (:meth:`_own_state`) and, under ``sibling{i}__``, those
        of each solver :meth:`sibling` has made (the Newton loop's factorisation without held DOFs has its own)."""
        st = dict(self._own_state())
        for i, other in enumerate(self._siblings):
            for key, value in other.state().items():
                st[f"sibling{i}__{key}"] = value
        return st

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`state`: this solver's part now, each sibling's when it exists (now, or when
        :meth:`sibling` makes it). Keys not written by :meth:`state` are ignored."""
        own: dict[str, np.ndarray] = {}
        siblings: dict[int, dict[str, np.ndarray]] = {}
        for key, value in state.items():
            match = _SIBLING_KEY.fullmatch(key)
            if match is None:
                own[key] = value
            else:
                siblings.setdefault(int(match.group(1)), {})[match.group(2)] = value
        self._load_own_state(own)
        self._sibling_states = {}
        for i, st in siblings.items():
            if i < len(self._siblings):
                self._siblings[i].load_state(st)
            else:
                self._sibling_states[i] = st

    def _own_state(self) -> dict[str, np.ndarray]:
        """This backend's history-dependent choices (see :class:`~idp.solver.cholmod_cvxopt.CholmodSolver`); none
        here."""
        return {}

    def _load_own_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`_own_state` (nothing here)."""
        return None

    def sibling(self) -> LinearSolver:
        """A solver of the same kind and settings with its own pattern work (a second system solved beside this
        one, e.g. :class:`idp.solver.held_reduction.HeldReduction`'s), counting into the same ``stats``, checked
        by the same memory guard, and kept in this solver's :meth:`state`."""
        other = self._fresh()
        other.stats = self.stats
        other.memory_guard = self.memory_guard
        pending = self._sibling_states.pop(len(self._siblings), None)
        if pending is not None:
            other.load_state(pending)
        self._siblings.append(other)
        return other

    def _fresh(self) -> LinearSolver:
        return type(self)(dofs_per_node=self.dofs_per_node)

    def _check_rhs(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=np.float64)
        if b.shape[0] != self.n or b.ndim not in (1, 2):
            raise ValueError(f"right-hand side has shape {b.shape}, expected ({self.n},) or ({self.n}, k)")
        return b

    @staticmethod
    def _check_finite_matrix(data: np.ndarray) -> None:
        if not np.isfinite(data).all():
            raise SolverError("linear system matrix has non-finite entries")

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dofs_per_node={self.dofs_per_node})"


# --------------------------------------------------------------------------- scipy


class ScipySolver(LinearSolver):
    """SuperLU without pivoting in symmetric mode (always available; slower than CHOLMOD).

    With pymetis, the matrix is permuted by the vertex-graph nested dissection
    (computed once per pattern, together with the data index map of the permuted
    matrix) and factorised with ``permc_spec="NATURAL"``; without it SuperLU orders
    with ``MMD_AT_PLUS_A`` on every factorisation. SuperLU's own symbolic step is part
    of every numeric factorisation and is timed as ``numeric``.

    Memory (:meth:`factor_bytes`): SuperLU keeps L supernodal (dense supernode blocks, 8 B per entry) and U by
    columns (value + int32 row index, 12 B per entry); without pivoting U has the pattern of Lᵀ. Measured RSS
    growth of ``splu`` on the 3D grid matrices of bench/bench_linear.py with the ND ordering: 83 MB at 12K DOF,
    328 MB at 32K DOF; the model says 86 and 339 MB. Without pymetis SuperLU orders inside ``splu`` and the
    memory guard has no ordering to count with (it skips the check).
    """

    name = "scipy"

    def __init__(self, dofs_per_node: int = 3, use_metis: bool | None = None) -> None:
        super().__init__(dofs_per_node)
        self.use_metis = have_pymetis() if use_metis is None else bool(use_metis)
        self._pattern = PatternCache()
        self._perm: np.ndarray | None = None
        self._pindptr: np.ndarray | None = None
        self._pindices: np.ndarray | None = None
        self._pmap: np.ndarray | None = None
        self._lu: Any = None

    def _fresh(self) -> ScipySolver:
        return ScipySolver(dofs_per_node=self.dofs_per_node, use_metis=self.use_metis)

    def _analyse(self, indptr: np.ndarray, indices: np.ndarray, n: int) -> None:
        """Ordering and data map of the permuted matrix for a new pattern."""
        t0 = time.perf_counter()
        if self.use_metis:
            p = nested_dissection_ordering(indptr, indices, n, self.dofs_per_node)
            t1 = time.perf_counter()
            self._check_memory(indptr, indices, n, p)
            # Permute a matrix whose values are entry numbers: its data is the map.
            M = sp.csr_matrix((np.arange(indices.shape[0], dtype=np.int64), indices, indptr), shape=(n, n))
            Mp = M[p][:, p]
            Mp.sort_indices()
            self._perm, self._pindptr, self._pindices, self._pmap = p, Mp.indptr, Mp.indices, Mp.data
        else:
            self._check_memory(None, None, n, None)
            t1 = t0
            self._perm = self._pindptr = self._pindices = self._pmap = None
        t2 = time.perf_counter()
        self.stats["ordering"] += t1 - t0
        self.stats["symbolic"] += t2 - t1
        self._pattern.store(indptr, indices)
        self.stats["symbolic_analyses"] += 1

    def factor_bytes(self, counts: SymbolicCounts) -> tuple[int, int]:
        """L: 8 B per supernodal entry; U: 12 B per entry of Lᵀ; workspace: the permuted copy of A and O(n) ints."""
        return 8 * counts.supernodal_values + 12 * counts.nnz_factor, 8 * counts.nnz_matrix + 64 * counts.n

    def factorize(self, A: sp.spmatrix) -> None:
        indptr, indices, data, n = compressed_arrays(A)
        self._check_finite_matrix(data)
        self._lu = None
        if self._pattern.same(indptr, indices):
            self.stats["symbolic_reuses"] += 1
        else:
            self._analyse(indptr, indices, n)
        self.n = n
        t0 = time.perf_counter()
        # Symmetric A: CSR arrays read as CSC describe the same matrix.
        if self._perm is not None:
            M = sp.csc_matrix((data[self._pmap], self._pindices, self._pindptr), shape=(n, n))
            spec = "NATURAL"
        else:
            M = sp.csc_matrix((data, indices, indptr), shape=(n, n))
            spec = "MMD_AT_PLUS_A"
        import scipy.sparse.linalg as spla  # imported here: the CHOLMOD path needs neither it nor scipy.linalg (10 MB)

        try:
            lu = spla.splu(M, permc_spec=spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        except RuntimeError as exc:  # "Factor is exactly singular"
            raise NotPositiveDefinite(f"SuperLU factorisation failed: {exc}") from exc
        finally:
            self.stats["numeric"] += time.perf_counter() - t0
        self._lu = lu
        self.stats["factorizations"] += 1

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self._lu is None:
            raise SolverError("solve() called without a successful factorize()")
        b = self._check_rhs(b)
        t0 = time.perf_counter()
        if self._perm is not None:
            p = self._perm
            x = np.empty_like(b)
            x[p] = self._lu.solve(np.ascontiguousarray(b[p]))
        else:
            x = self._lu.solve(b)
        self.stats["solve"] += time.perf_counter() - t0
        if not np.isfinite(x).all():
            raise NotPositiveDefinite("SuperLU produced a non-finite solution (matrix not SPD or singular)")
        return x


# --------------------------------------------------------------------------- factory

_cholmod_import_error: list[BaseException | None] = []


def _cholmod_class() -> type[LinearSolver] | None:
    """The CHOLMOD solver class, or None when cvxopt cannot be imported."""
    try:
        from idp.solver.cholmod_cvxopt import CholmodSolver
    except ImportError as exc:
        _cholmod_import_error[:] = [exc]
        return None
    return CholmodSolver


def available_solvers() -> list[str]:
    """Names of the backends usable in this environment (best first)."""
    names = []
    if _cholmod_class() is not None:
        names.append("cholmod")
    names.append("scipy")
    return names


def make_linear_solver(name: str = "auto", dofs_per_node: int = 3) -> LinearSolver:
    """Create a linear solver: ``"auto"`` (CHOLMOD if cvxopt imports, else scipy),
    ``"cholmod"`` or ``"scipy"``."""
    key = str(name).lower()
    if key not in _CHOICES:
        raise ValueError(f"unknown linear solver {name!r}; choose one of {', '.join(map(repr, _CHOICES))}")
    if key in ("auto", "cholmod"):
        cls = _cholmod_class()
        if cls is not None:
            return cls(dofs_per_node=dofs_per_node)
        if key == "cholmod":
            err = _cholmod_import_error[0] if _cholmod_import_error else None
            raise SolverError(
                "linear solver 'cholmod' needs cvxopt (GPL-3), which is not importable"
                f" ({err}); install it with `pip install idp[cholmod]` or use 'scipy'"
            ) from err
    return ScipySolver(dofs_per_node=dofs_per_node)
