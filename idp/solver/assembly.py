"""Sparse assembly of the Newton matrix on the free degrees of freedom.

The elastic + mass part has a fixed pattern: it is built once, and every Newton iteration
only scatters new element values into it with ``np.bincount`` (no COO→CSR rebuild).
Contact Hessians (whose pattern changes with the active set) are added on top.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class FreeDofMap:
    """Maps global DOFs (vertex·d + coordinate) to the numbering of the free (unpinned) DOFs."""

    def __init__(self, free_mask: np.ndarray):
        self.free_mask = np.asarray(free_mask, dtype=bool)
        self.global_to_free = np.full(self.free_mask.size, -1, dtype=np.int64)
        self.free_dofs = np.flatnonzero(self.free_mask)
        self.global_to_free[self.free_dofs] = np.arange(self.free_dofs.size)

    @property
    def num_free(self) -> int:
        return int(self.free_dofs.size)


class FixedPatternAssembler:
    """Assembles Σ_e H_e (element blocks) + diag(d) into a CSR matrix with a pattern fixed at construction."""

    def __init__(self, element_dofs: list[np.ndarray], dof_map: FreeDofMap):
        self.dof_map = dof_map
        n = dof_map.num_free
        rows_all, cols_all, valid_all = [], [], []
        for dofs in element_dofs:
            k = dofs.shape[1]
            local = dof_map.global_to_free[dofs]  # (m, k)
            r = np.repeat(local, k, axis=1).ravel()
            c = np.tile(local, (1, k)).ravel()
            valid = (r >= 0) & (c >= 0)
            rows_all.append(r)
            cols_all.append(c)
            valid_all.append(valid)
        diag = np.arange(n, dtype=np.int64)
        rows = np.concatenate([*(r[v] for r, v in zip(rows_all, valid_all)), diag])
        cols = np.concatenate([*(c[v] for c, v in zip(cols_all, valid_all)), diag])
        keys = rows * n + cols
        unique_keys, scatter = np.unique(keys, return_inverse=True)
        self.nnz = int(unique_keys.size)
        pattern_rows = unique_keys // n
        self.indices = (unique_keys % n).astype(np.int32)
        self.indptr = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(np.bincount(pattern_rows, minlength=n), out=self.indptr[1:])
        n_elem_entries = [int(v.sum()) for v in valid_all]
        offsets = np.cumsum([0, *n_elem_entries])
        self._element_scatter = [scatter[offsets[i]: offsets[i + 1]] for i in range(len(element_dofs))]
        self._element_valid = valid_all
        self._diag_scatter = scatter[offsets[-1]:]
        self.shape = (n, n)

    def assemble(self, element_blocks: list[np.ndarray], weights: list[float], diagonal: np.ndarray) -> sp.csr_matrix:
        """Σ_i weights[i]·blocks[i] scattered into the pattern, plus ``diagonal`` (free DOFs)."""
        data = np.bincount(self._diag_scatter, weights=diagonal, minlength=self.nnz)
        for blocks, w, idx, valid in zip(element_blocks, weights, self._element_scatter, self._element_valid):
            vals = blocks.reshape(-1)[valid]
            data += w * np.bincount(idx, weights=vals, minlength=self.nnz)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def restrict_collision_hessian(H: sp.spmatrix, collision_dof_to_free: np.ndarray, n_free: int) -> sp.csr_matrix:
    """Map a Hessian on collision-mesh DOFs to the free-DOF numbering, dropping pinned DOFs."""
    H = H.tocoo()
    r = collision_dof_to_free[H.row]
    c = collision_dof_to_free[H.col]
    keep = (r >= 0) & (c >= 0)
    return sp.csr_matrix((H.data[keep], (r[keep], c[keep])), shape=(n_free, n_free))
