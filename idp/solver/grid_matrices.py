"""Structured-grid sparsity for synthetic Newton-like matrices (used by the linear-solver tests and benchmark)."""

from __future__ import annotations

import numpy as np


def grid_edges(nx: int) -> np.ndarray:
    """Edges of the Freudenthal tet subdivision of an nx³ vertex grid (14-neighbour stencil)."""
    idx = np.arange(nx**3).reshape(nx, nx, nx)
    out = []
    for d in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)]:
        a = idx[: nx - d[0], : nx - d[1], : nx - d[2]]
        b = idx[d[0] :, d[1] :, d[2] :]
        out.append(np.stack([a.ravel(), b.ravel()], 1))
    return np.concatenate(out)


def grid_block_pattern(nx: int, d: int = 3):
    """Symmetric pattern (all ones, both triangles, diagonal included) of ``d`` DOFs per vertex of the
    :func:`grid_edges` grid: the block structure of a 3D tet-mesh Hessian, as CSR."""
    import scipy.sparse as sp

    e = grid_edges(nx)
    nv = nx**3
    V = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv))
    V = V + V.T + sp.eye(nv)
    return sp.kron(V, np.ones((d, d)), format="csr")
