"""The compiled lower-triangle pattern walks against the same sets built by scipy and numpy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from idp.solver.linear import vertex_graph
from idp.solver.lower_pattern import (
    locate_entries,
    lower_columns,
    symmetric_from_lower,
    union_columns,
    vertex_graph_from_lower,
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


def _lower(A: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    lptr, sel, _ = lower_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))
    return lptr, A.indices.astype(np.int32)[sel]


def _keys(ptr: np.ndarray, rows: np.ndarray) -> np.ndarray:
    n = ptr.size - 1
    return np.repeat(np.arange(n, dtype=np.int64), np.diff(ptr)) * max(n, 1) + rows


@pytest.mark.parametrize("seed", range(4))
def test_lower_columns_are_the_lower_triangle(seed: int) -> None:
    A = _symmetric_pattern(60, 0.08, seed)
    lptr, sel, diagonal = lower_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))
    assert diagonal
    L = sp.tril(A).tocsc()
    L.sort_indices()
    np.testing.assert_array_equal(lptr, L.indptr)
    np.testing.assert_array_equal(A.indices[sel], L.indices)
    assert sel.sum() == L.nnz


def test_lower_columns_notice_a_missing_diagonal_entry() -> None:
    A = _symmetric_pattern(30, 0.1, 7).tolil()
    A[12, 12] = 0
    A = A.tocsr()
    A.eliminate_zeros()
    assert not lower_columns(A.indptr.astype(np.int64), A.indices.astype(np.int32))[2]
    empty_row = sp.csr_matrix((3, 3))  # a row without any entry at or right of its diagonal
    assert not lower_columns(empty_row.indptr.astype(np.int64), empty_row.indices.astype(np.int32))[2]


@pytest.mark.parametrize("seed", range(4))
def test_merge_walks_match_set_operations(seed: int) -> None:
    n = 80
    old = _symmetric_pattern(n, 0.05, seed)
    new = _symmetric_pattern(n, 0.05, 100 + seed)
    aptr, arow = _lower(old)
    lptr, lrow = _lower(new)
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


@pytest.mark.parametrize("seed", range(3))
def test_symmetric_pattern_from_the_lower_triangle(seed: int) -> None:
    A = _symmetric_pattern(50, 0.1, seed)
    indptr, indices = symmetric_from_lower(*_lower(A))
    np.testing.assert_array_equal(indptr, A.indptr)
    np.testing.assert_array_equal(indices, A.indices)
    assert indices.dtype == np.int32 and indptr.dtype == np.int32


@pytest.mark.parametrize("d", [1, 2, 3])
def test_vertex_graph_from_the_lower_triangle(d: int) -> None:
    A = _symmetric_pattern(20 * d, 0.06, d)
    xadj, adjncy = vertex_graph_from_lower(*_lower(A), d)
    ref_xadj, ref_adjncy = vertex_graph(A.indptr, A.indices, A.shape[0], d)
    np.testing.assert_array_equal(xadj, ref_xadj)
    np.testing.assert_array_equal(adjncy, ref_adjncy)
