"""Exact symbolic Cholesky counts: against graph elimination, dense Cholesky and CHOLMOD's own factor."""

import numpy as np
import pytest
import scipy.sparse as sp

from idp.solver.grid_matrices import grid_block_pattern, grid_edges
from idp.solver.linear import have_pymetis, nested_dissection_ordering
from idp.solver.symbolic import cholesky_nnz, column_counts, elimination_tree, symbolic_counts


def _random_pattern(rng: np.random.Generator, n: int, density: float) -> sp.csr_matrix:
    S = sp.random(n, n, density=density, random_state=int(rng.integers(1 << 30)), format="csr")
    return (S + S.T + sp.eye(n)).tocsr()


def _eliminate(A: sp.csr_matrix, perm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column counts and elimination tree by eliminating the graph of A[p][:, p] vertex by vertex (reference)."""
    n = A.shape[0]
    B = (A[perm][:, perm] != 0).toarray()
    B |= B.T
    adj = [set(np.flatnonzero(B[i])) - {i} for i in range(n)]
    counts = np.zeros(n, dtype=np.int64)
    parent = np.full(n, -1, dtype=np.int64)
    for k in range(n):
        higher = {j for j in adj[k] if j > k}
        counts[k] = len(higher) + 1
        if higher:
            parent[k] = min(higher)
        for a in higher:
            adj[a] |= higher - {a}
    return counts, parent


def test_counts_and_tree_match_graph_elimination():
    rng = np.random.default_rng(7)
    for _ in range(150):
        n = int(rng.integers(1, 45))
        A = _random_pattern(rng, n, float(rng.uniform(0.01, 0.3)))
        perm = rng.permutation(n)
        ref_counts, ref_parent = _eliminate(A, perm)
        np.testing.assert_array_equal(column_counts(A.indptr, A.indices, n, perm), ref_counts)
        np.testing.assert_array_equal(elimination_tree(A.indptr, A.indices, n, perm), ref_parent)


def test_nnz_matches_dense_cholesky():
    """Random SPD values on random patterns: the numerical factor has exactly the symbolic nonzeros."""
    rng = np.random.default_rng(3)
    for _ in range(60):
        n = int(rng.integers(2, 60))
        A = _random_pattern(rng, n, float(rng.uniform(0.02, 0.2)))
        A.data = rng.uniform(-1.0, 1.0, A.data.size)
        A = (A + A.T).tocsr()
        A = A + sp.eye(n) * (abs(A).sum(axis=1).max() + 1.0)  # diagonally dominant: SPD
        A = A.tocsr()
        perm = rng.permutation(n)
        L = np.linalg.cholesky(A.toarray()[np.ix_(perm, perm)])
        assert cholesky_nnz(A.indptr, A.indices, n, perm) == np.count_nonzero(L)


def test_csc_and_csr_of_a_symmetric_pattern_agree_and_natural_order_default():
    rng = np.random.default_rng(1)
    A = _random_pattern(rng, 80, 0.05)
    C = A.tocsc()
    assert cholesky_nnz(A.indptr, A.indices, 80) == cholesky_nnz(C.indptr, C.indices, 80, np.arange(80))


def test_small_and_degenerate_patterns():
    assert symbolic_counts(np.zeros(1, dtype=np.int32), np.zeros(0, dtype=np.int32), 0).nnz_factor == 0
    D = sp.eye(5, format="csr")
    c = symbolic_counts(D.indptr, D.indices, 5)
    assert (c.nnz_factor, c.supernodes, c.supernodal_values, c.max_update) == (5, 5, 5, 0)
    full = sp.csr_matrix(np.ones((6, 6)))
    c = symbolic_counts(full.indptr, full.indices, 6, np.array([3, 1, 0, 5, 2, 4]))
    assert c.nnz_factor == 21 and c.supernodes == 1 and c.supernodal_values == 36
    with pytest.raises(ValueError, match="permutation"):
        symbolic_counts(full.indptr, full.indices, 6, np.array([0, 0, 1, 2, 3, 4]))


def test_supernodal_sizes_bound_the_factor():
    A = sp.csr_matrix((np.ones(len(grid_edges(6))), grid_edges(6).T), shape=(216, 216))
    A = (A + A.T + sp.eye(216)).tocsr()
    c = symbolic_counts(A.indptr, A.indices, 216, np.random.default_rng(0).permutation(216))
    assert c.nnz_factor <= c.supernodal_values <= 216 * c.nnz_factor
    assert 1 <= c.supernodes <= 216 and c.nnz_matrix == A.nnz


@pytest.mark.skipif(not have_pymetis(), reason="needs pymetis")
def test_matches_cholmod_factor():
    """CHOLMOD's simplicial factor under the same METIS ordering has exactly the counted nonzeros."""
    cvxopt = pytest.importorskip("cvxopt")
    from cvxopt import cholmod

    A = grid_block_pattern(7)
    n = A.shape[0]
    A = (A + sp.eye(n) * 100.0).tocsr()  # values: SPD
    perm = nested_dissection_ordering(A.indptr, A.indices, n, 3)
    lower = sp.tril(A).tocoo()
    S = cvxopt.spmatrix(lower.data, lower.row.astype(int), lower.col.astype(int), (n, n))
    saved = dict(cholmod.options)
    try:
        cholmod.options.update(supernodal=0, postorder=True, nmethods=1)
        F = cholmod.symbolic(S, p=cvxopt.matrix(perm), uplo="L")
        cholmod.numeric(S, F)
        L = cholmod.getfactor(F)
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)
    c = symbolic_counts(A.indptr, A.indices, n, perm)
    assert c.nnz_factor == len(L.V)
    # and a fill-reducing ordering beats the natural one on a 3D grid
    assert c.nnz_factor < cholesky_nnz(A.indptr, A.indices, n)
