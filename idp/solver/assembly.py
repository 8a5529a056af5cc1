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
        key_parts = []
        for dofs in element_dofs:
            k = dofs.shape[1]
            local = dof_map.global_to_free[dofs]  # (m, k), -1 for pinned DOFs
            keys = (local[:, :, None] * n + local[:, None, :]).reshape(-1)
            keys[((local[:, :, None] < 0) | (local[:, None, :] < 0)).reshape(-1)] = -1
            key_parts.append(keys)
        diag = np.arange(n, dtype=np.int64) * (n + 1)
        all_keys = np.concatenate([*key_parts, diag])
        del key_parts
        unique_keys, scatter = np.unique(all_keys, return_inverse=True)
        del all_keys
        has_pinned = unique_keys.size and unique_keys[0] < 0
        if has_pinned:  # entries touching a pinned DOF go to a dummy slot (index nnz) that is dropped
            unique_keys = unique_keys[1:]
            scatter -= 1
            scatter[scatter < 0] = unique_keys.size
        self.nnz = int(unique_keys.size)
        scatter = scatter.astype(np.int32 if self.nnz < 2**31 - 1 else np.int64)
        self.indices = (unique_keys % n).astype(np.int32)
        self.indptr = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(np.bincount(unique_keys // n, minlength=n), out=self.indptr[1:])
        sizes = [d.shape[0] * d.shape[1] ** 2 for d in element_dofs]
        offsets = np.cumsum([0, *sizes])
        self._element_scatter = [scatter[offsets[i]: offsets[i + 1]] for i in range(len(element_dofs))]
        self._diag_scatter = scatter[offsets[-1]:]
        self.shape = (n, n)

    def assemble_data(self, element_blocks: list[np.ndarray], weights: list[float], diagonal: np.ndarray) -> np.ndarray:
        """Values of Σ_i weights[i]·blocks[i] + diag(``diagonal``) on the fixed pattern."""
        data = np.bincount(self._diag_scatter, weights=diagonal, minlength=self.nnz + 1)
        for blocks, w, idx in zip(element_blocks, weights, self._element_scatter):
            data += w * np.bincount(idx, weights=blocks.reshape(-1), minlength=self.nnz + 1)
        return data[: self.nnz]

    def assemble(self, element_blocks: list[np.ndarray], weights: list[float], diagonal: np.ndarray) -> sp.csr_matrix:
        """Σ_i weights[i]·blocks[i] scattered into the pattern, plus ``diagonal`` (free DOFs)."""
        data = self.assemble_data(element_blocks, weights, diagonal)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def restrict_collision_hessian(H: sp.spmatrix, collision_dof_to_free: np.ndarray, n_free: int) -> sp.csr_matrix:
    """Map a Hessian on collision-mesh DOFs to the free-DOF numbering, dropping pinned DOFs."""
    H = H.tocoo()
    r = collision_dof_to_free[H.row]
    c = collision_dof_to_free[H.col]
    keep = (r >= 0) & (c >= 0)
    return sp.csr_matrix((H.data[keep], (r[keep], c[keep])), shape=(n_free, n_free))
