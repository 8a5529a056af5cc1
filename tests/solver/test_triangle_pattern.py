"""The compiled triangle pattern walks against the same sets built by scipy and numpy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from idp.solver.linear import vertex_graph
from idp.solver.triangle_pattern import (
    locate_entries,
    symmetric_from_triangle,
    union_columns,
    upper_columns,
    vertex_graph_from_triangle,
)


def _symmetric_pattern(n: int, density: float, seed: int, diagonal: bool = True) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, random_state=rng, format="csr")
    A = A + A.T
    if diagonal:
        A = A + sp.identity(n, format="csr")
    A = A.tocsr()
    A.sum_duplicates()
    A.data[:] = 1.0
    return A


def _upper(A: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    uptr, sel, _ = upper_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))
    return uptr, A.indices.astype(np.int32)[sel]


def _triangle(A: sp.csr_matrix, which: str) -> tuple[np.ndarray, np.ndarray]:
    """The columns of one triangle of A, built by scipy."""
    T = (sp.tril(A) if which == "lower" else sp.triu(A)).tocsc()
    T.sort_indices()
    return T.indptr.astype(np.int64), T.indices.astype(np.int32)


def _keys(ptr: np.ndarray, rows: np.ndarray) -> np.ndarray:
    n = ptr.size - 1
    return np.repeat(np.arange(n, dtype=np.int64), np.diff(ptr)) * max(n, 1) + rows


@pytest.mark.parametrize("seed", range(4))
def test_upper_columns_are_the_upper_triangle(seed: int) -> None:
    A = _symmetric_pattern(60, 0.08, seed)
    uptr, sel, diagonal = upper_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))
    assert diagonal
    U = sp.triu(A).tocsc()
    U.sort_indices()
    np.testing.assert_array_equal(uptr, U.indptr)
    np.testing.assert_array_equal(A.indices[sel], U.indices)
    assert sel.sum() == U.nnz
    values = np.arange(A.nnz, dtype=float)  # the selected CSR values are the upper triangle's in CSC order
    Av = sp.csr_matrix((values, A.indices, A.indptr), shape=A.shape)
    np.testing.assert_array_equal(values[sel], sp.tril(Av).tocsr().data)


def test_upper_columns_notice_a_missing_diagonal_entry() -> None:
    A = _symmetric_pattern(30, 0.1, 7).tolil()
    A[12, 12] = 0
    A = A.tocsr()
    A.eliminate_zeros()
    assert not upper_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))[2]
    empty_row = sp.csr_matrix((3, 3))  # a row without any entry at or left of its diagonal
    assert not upper_columns(empty_row.indptr.astype(np.int64), empty_row.indices.astype(np.int32))[2]


@pytest.mark.parametrize("seed", range(4))
def test_merge_walks_match_set_operations(seed: int) -> None:
    n = 80
    old = _symmetric_pattern(n, 0.05, seed)
    new = _symmetric_pattern(n, 0.05, 100 + seed)
    aptr, arow = _upper(old)
    lptr, lrow = _upper(new)
    ka, kl = _keys(aptr, arow), _keys(lptr, lrow)
    found = np.zeros(arow.size, dtype=bool)
    n_new = locate_entries(lptr, lrow, aptr, arow, found)
    assert n_new == np.setdiff1d(kl, ka).size > 0
    np.testing.assert_array_equal(ka[found], np.intersect1d(ka, kl))

    uptr, urow, mask, new_rows, new_cols = union_columns(lptr, lrow, aptr, arow, n_new)
    ku = _keys(uptr, urow)
    np.testing.assert_array_equal(ku, np.union1d(ka, kl))
    np.testing.assert_array_equal(ku[mask], kl)  # the current entries, in their own order
    np.testing.assert_array_equal(new_cols * n + new_rows, np.setdiff1d(kl, ka))

    # the new pattern inside the union: no new entry, and each of its entries found where the union's mask says
    found = np.zeros(urow.size, dtype=bool)
    assert locate_entries(lptr, lrow, uptr, urow, found) == 0
    np.testing.assert_array_equal(found, mask)
    found = np.zeros(arow.size, dtype=bool)
    assert locate_entries(aptr, arow, aptr, arow, found) == 0
    assert found.all()


@pytest.mark.parametrize("which", ["lower", "upper"])
@pytest.mark.parametrize("seed", range(3))
def test_symmetric_pattern_from_either_triangle(seed: int, which: str) -> None:
    A = _symmetric_pattern(50, 0.1, seed)
    indptr, indices = symmetric_from_triangle(*_triangle(A, which))
    np.testing.assert_array_equal(indptr, A.indptr)
    np.testing.assert_array_equal(indices, A.indices)
    assert indices.dtype == np.int32 and indptr.dtype == np.int32


@pytest.mark.parametrize("which", ["lower", "upper"])
@pytest.mark.parametrize("d", [1, 2, 3])
def test_vertex_graph_from_either_triangle(d: int, which: str) -> None:
    A = _symmetric_pattern(20 * d, 0.06, d)
    xadj, adjncy = vertex_graph_from_triangle(*_triangle(A, which), d)
    ref_xadj, ref_adjncy = vertex_graph(A.indptr, A.indices, A.shape[0], d)
    np.testing.assert_array_equal(xadj, ref_xadj)
    np.testing.assert_array_equal(adjncy, ref_adjncy)
