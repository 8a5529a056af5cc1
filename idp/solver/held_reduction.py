"""Held DOFs out of the factorisation: solve on the principal submatrix of the DOFs that still move.

When the step constraint holds DOFs (§4.3 targets met, fixed handles, the prescribed head of an animation repair),
the Newton loop zeroes their rows and columns except the diagonal (:meth:`idp.solver.newton.StepSolver._hold`), so
the direction is exactly 0 there. Factorising that matrix as it stands costs as much as factorising the whole
system: the zeros are explicit entries of the pattern, and CHOLMOD's symbolic analysis and supernodal numeric
factorisation treat them as nonzeros (fill and flops included). In an animation repair half of the mesh is
held in most steps.

:class:`HeldReduction` factorises only ``H[k, k]`` (k: the DOFs not held) with its own backend, so the pattern
work of the full system and of the reduced one are both kept between steps, and answers solves with the same
vector the zeroed full matrix would give: ``x_k = H[k, k]⁻¹ b_k`` and ``x_h = b_h / H_hh`` (the held rows are
diagonal). The index map from the full matrix to the submatrix is built once per (pattern, held set).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from idp.errors import SolverError
from idp.solver.linear import LinearSolver, NotPositiveDefinite, PatternCache


def keeps_vertex_groups(held: np.ndarray, dofs_per_node: int) -> bool:
    """Whether ``held`` holds whole groups of ``dofs_per_node`` consecutive DOFs, so the kept DOFs keep the
    per-vertex grouping the backend's ordering relies on."""
    d = int(dofs_per_node)
    if d <= 1:
        return True
    if held.size % d:
        return False
    groups = held.reshape(-1, d)
    return bool(np.all(groups.all(axis=1) == groups.any(axis=1)))


class HeldReduction:
    """Factorise-then-solve on the DOFs not held, with the interface of a full-size solve."""

    def __init__(self, backend: LinearSolver) -> None:
        """``backend``: a solver of its own (see :meth:`LinearSolver.sibling`): its symbolic analysis is the reduced
        pattern's and must not evict the full system's."""
        self.backend = backend
        self._pattern = PatternCache()
        self._held: np.ndarray | None = None
        self._map: tuple[np.ndarray, sp.csr_matrix, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._held_diagonal: np.ndarray | None = None
        self._factored = False

    def _index_map(self, H: sp.csr_matrix, held: np.ndarray) -> None:
        """Positions in ``H.data`` of the kept block's entries and that block's own (read-only) pattern."""
        n = H.shape[0]
        keep = ~held
        rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(H.indptr))
        cols = H.indices
        entries = np.flatnonzero(keep[rows] & keep[cols])
        renumber = np.cumsum(keep, dtype=np.int64) - 1
        kept = np.flatnonzero(keep)
        counts = np.bincount(renumber[rows[entries]], minlength=kept.size)
        indptr = np.zeros(kept.size + 1, dtype=H.indptr.dtype)
        np.cumsum(counts, out=indptr[1:])
        indices = renumber[cols[entries]].astype(H.indices.dtype)
        indptr.flags.writeable = False  # frozen: the backend then compares patterns by identity
        indices.flags.writeable = False
        block = sp.csr_matrix((np.zeros(entries.size), indices, indptr), shape=(kept.size, kept.size))
        held_rows = np.flatnonzero(held)
        on_diagonal = np.flatnonzero(rows == cols)
        position = np.full(n, -1, dtype=np.int64)  # each row's diagonal entry in H.data
        position[rows[on_diagonal]] = on_diagonal
        diagonal = position[held_rows]
        if np.any(diagonal < 0):
            raise NotPositiveDefinite("a held DOF has no diagonal entry")
        self._map = (entries, block, kept, held_rows, diagonal)
        self._held = held.copy()
        self._pattern.store(H.indptr, H.indices)

    def factorize(self, H: sp.csr_matrix, held: np.ndarray) -> None:
        """Factorise the block of ``H`` (canonical CSR, rows and columns of held DOFs zeroed but for the diagonal)
        that the DOFs not in ``held`` form."""
        self._factored = False
        if (
            self._map is None
            or self._held is None
            or not self._pattern.same(H.indptr, H.indices)
            or not np.array_equal(self._held, held)
        ):
            self._index_map(H, held)
        assert self._map is not None
        entries, block, _, _, diagonal = self._map
        block.data = H.data[entries]
        self._held_diagonal = H.data[diagonal]
        if np.any(self._held_diagonal <= 0.0):
            raise NotPositiveDefinite("a held DOF has a non-positive diagonal entry")
        self.backend.factorize(block)
        self._factored = True

    def solve(self, b: np.ndarray) -> np.ndarray:
        """The solution of the full zeroed system for ``b`` of shape (n,) or (n, k)."""
        if not self._factored or self._map is None or self._held_diagonal is None:
            raise SolverError("solve() called without a successful factorize()")
        _, _, kept, held_rows, _ = self._map
        b = np.asarray(b, dtype=np.float64)
        x = np.empty_like(b)
        x[kept] = self.backend.solve(b[kept])
        scale = self._held_diagonal if b.ndim == 1 else self._held_diagonal[:, None]
        x[held_rows] = b[held_rows] / scale
        return x
