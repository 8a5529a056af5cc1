"""One triangle of a symmetric sparsity pattern as compressed columns, merged with an analysed one.

A Cholesky backend that keeps its symbolic factorisation across Newton iterations needs, whenever the matrix's
pattern changes: the new triangle, whether it lies inside the analysed pattern (then the old analysis serves, with
explicit zeros), else the union of the two, where each entry of the matrix sits in the pattern it factorises, and
the symmetric and vertex-graph forms of that pattern for the fill-reducing ordering and the memory count. Every
step here is one compiled pass over sorted columns: merge walks instead of sorted int64 keys, binary searches and
scipy's triplet conversions (at the Fig. 12 cat's 22K DOFs: 35 → 6 ms per changed pattern, see
:mod:`idp.solver.cholmod_cvxopt`).

Conventions: a symmetric CSR with sorted rows (scipy's canonical format); its upper triangle in CSC is row r's
entries c <= r as column r (the same arrays by symmetry: a prefix of each row, ending at the diagonal). CHOLMOD
factors that triangle with one permuted transpose where the lower one costs two (:mod:`idp.solver.cholmod_cvxopt`).
The merge walks and the symmetric forms take the columns of either triangle. Column pointers are int64, row indices
int32 (one compiled specialisation each).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "locate_entries",
    "symmetric_from_triangle",
    "union_columns",
    "upper_columns",
    "vertex_graph_from_triangle",
]


@numba.njit(cache=True)
def upper_columns(indptr: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:  # pragma: no cover
    """(uptr, sel, diagonal): the column pointers of the upper triangle of a symmetric CSR with sorted rows
    (column r = the entries c <= r of row r, so its rows are ``indices[sel]``), the mask ``sel`` of those entries
    in CSR order, and whether every column ends at its diagonal entry."""
    n = indptr.size - 1
    uptr = np.zeros(n + 1, np.int64)
    sel = np.zeros(indices.size, np.bool_)
    diagonal = True
    for r in range(n):
        count = 0
        last = -1
        for k in range(indptr[r], indptr[r + 1]):
            if indices[k] > r:
                break
            sel[k] = True
            last = indices[k]
            count += 1
        if last != r:
            diagonal = False
        uptr[r + 1] = uptr[r] + count
    return uptr, sel, diagonal


@numba.njit(cache=True)
def locate_entries(
    lptr: np.ndarray, lrow: np.ndarray, aptr: np.ndarray, arow: np.ndarray, found: np.ndarray
) -> int:  # pragma: no cover
    """Mark in ``found`` (a bool per entry of (aptr, arow), cleared by the caller) the entries that the column
    pattern (lptr, lrow) also has, and return how many of its entries (aptr, arow) lacks (same number of columns,
    rows sorted in each column)."""
    missing = 0
    for j in range(lptr.size - 1):
        p, end = aptr[j], aptr[j + 1]
        for k in range(lptr[j], lptr[j + 1]):
            r = lrow[k]
            while p < end and arow[p] < r:
                p += 1
            if p < end and arow[p] == r:
                found[p] = True
                p += 1
            else:
                missing += 1
    return missing


@numba.njit(cache=True)
def union_columns(
    lptr: np.ndarray, lrow: np.ndarray, aptr: np.ndarray, arow: np.ndarray, n_new: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """(uptr, urow, mask, new_rows, new_cols): the union of two column patterns whose first has ``n_new`` entries
    the second lacks, the mask of the first's entries in it, and the row and column of each of those new entries
    (column-major, rows increasing)."""
    n = lptr.size - 1
    size = arow.size + n_new
    uptr = np.zeros(n + 1, np.int64)
    urow = np.empty(size, np.int32)
    mask = np.zeros(size, np.bool_)
    new_rows = np.empty(n_new, np.int64)
    new_cols = np.empty(n_new, np.int64)
    q = 0
    m = 0
    for j in range(n):
        p, pend = aptr[j], aptr[j + 1]
        k, kend = lptr[j], lptr[j + 1]
        while p < pend or k < kend:
            if k >= kend or (p < pend and arow[p] < lrow[k]):
                urow[q] = arow[p]
                p += 1
            elif p >= pend or lrow[k] < arow[p]:
                urow[q] = lrow[k]
                mask[q] = True
                new_rows[m] = lrow[k]
                new_cols[m] = j
                m += 1
                k += 1
            else:
                urow[q] = arow[p]
                mask[q] = True
                p += 1
                k += 1
            q += 1
        uptr[j + 1] = q
    return uptr, urow, mask, new_rows, new_cols


@numba.njit(cache=True)
def _symmetric_from_triangle(aptr: np.ndarray, arow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    n = aptr.size - 1
    counts = np.zeros(n, np.int64)
    for j in range(n):
        for p in range(aptr[j], aptr[j + 1]):
            i = arow[p]
            counts[j] += 1
            if i != j:
                counts[i] += 1
    indptr = np.zeros(n + 1, np.int64)
    for j in range(n):
        indptr[j + 1] = indptr[j] + counts[j]
    fill = indptr[:-1].copy()
    indices = np.empty(indptr[n], np.int32)
    # columns in increasing order. Lower triangle: row i receives its entries left of the diagonal (j < i, increasing)
    # before column i hands it its own diagonal and right part (sorted). Upper triangle: column i hands row i its
    # left part and diagonal (sorted) before any later column j > i adds j (increasing). Either way rows come out sorted
    for j in range(n):
        for p in range(aptr[j], aptr[j + 1]):
            i = arow[p]
            indices[fill[j]] = i
            fill[j] += 1
            if i != j:
                indices[fill[i]] = j
                fill[i] += 1
    return indptr, indices


def symmetric_from_triangle(aptr: np.ndarray, arow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices): the CSR, rows sorted, of the symmetric pattern whose lower or upper triangle has the
    columns (aptr, arow); int32 arrays where they fit, as scipy would make them."""
    indptr, indices = _symmetric_from_triangle(aptr, arow)
    if indptr[-1] < np.iinfo(np.int32).max:
        indptr = indptr.astype(np.int32)
    return indptr, indices


@numba.njit(cache=True)
def vertex_graph_from_triangle(
    aptr: np.ndarray, arow: np.ndarray, d: int
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """(xadj, adjncy) of the vertex graph of the symmetric pattern whose lower or upper triangle has the columns
    (aptr, arow), vertex v owning DOFs d·v .. d·v + d − 1: vertices adjacent when any of their DOFs couple, no
    self loops, neighbours sorted (the graph :func:`idp.solver.linear.vertex_graph` makes of the full pattern)."""
    nv = (aptr.size - 1) // d
    mark = np.full(nv, -1, np.int64)
    below = np.empty(arow.size, np.int64)  # per vertex column: its distinct neighbours in that triangle
    bptr = np.zeros(nv + 1, np.int64)
    degree = np.zeros(nv, np.int64)
    q = 0
    for vc in range(nv):
        for j in range(vc * d, vc * d + d):
            for p in range(aptr[j], aptr[j + 1]):
                vr = arow[p] // d
                if vr != vc and mark[vr] != vc:
                    mark[vr] = vc
                    below[q] = vr
                    q += 1
                    degree[vc] += 1
                    degree[vr] += 1
        bptr[vc + 1] = q
    xadj = np.zeros(nv + 1, np.int64)
    for v in range(nv):
        xadj[v + 1] = xadj[v] + degree[v]
    adjncy = np.empty(xadj[nv], np.int64)
    fill = xadj[:-1].copy()
    for vc in range(nv):
        # lower triangle: the lower neighbours (vc' < vc) arrived in increasing order from earlier columns, the higher
        # ones come in DOF-column order; upper triangle: nothing arrived yet, the lower ones come in DOF-column order
        # (the higher ones arrive later, increasing). The run in DOF-column order is sorted here
        start = fill[vc]
        for t in range(bptr[vc], bptr[vc + 1]):
            vr = below[t]
            adjncy[fill[vc]] = vr
            fill[vc] += 1
            adjncy[fill[vr]] = vc
            fill[vr] += 1
        for a in range(start + 1, fill[vc]):  # insertion sort of a short run (numba's sort compiles for seconds)
            v = adjncy[a]
            b = a - 1
            while b >= start and adjncy[b] > v:
                adjncy[b + 1] = adjncy[b]
                b -= 1
            adjncy[b + 1] = v
    return xadj, adjncy
