"""Symbolic Cholesky analysis: elimination tree, postorder, column counts and supernodes of L.

For a symmetric pattern ``A`` and the fill-reducing permutation ``p`` a solver uses (the factorised matrix is
``A[p][:, p]``), :func:`symbolic_counts` returns the exact number of nonzeros of the Cholesky factor L (with its
diagonal) without forming L, in time almost linear in nnz(A):

1. elimination tree by Liu's algorithm (ancestor links with path compression);
2. a postorder of the tree (depth-first, explicit stack);
3. column counts by the row-subtree / skeleton-leaf method of Gilbert, Ng and Peyton (1994): the nonzeros of
   row i of L are the tree nodes on the paths from the "leaves" of row i (entries A[i, j], j < i, none of whose
   tree descendants is an entry of row i) up to i. Each leaf adds +1 at itself, the least common ancestor of two
   consecutive leaves (found with a disjoint-set forest, as in Tarjan's offline LCA) −1, and every node −1 at its
   parent; the subtree sums of these weights are the column counts;
4. fundamental supernodes (a column joins its child's supernode when it is that child's only child and parent, and
   its count is one less): the storage of a supernodal factor that keeps each supernode as a dense
   rows × columns block, and the largest update block (rows below the supernode)², the workspace bound of a
   supernodal factorisation.

Everything is a numba kernel; no Python loop runs over rows or columns. The memory guard
(:mod:`idp.solver.memory`) turns these counts into bytes for the backend in use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = [
    "SymbolicCounts",
    "cholesky_flops",
    "cholesky_nnz",
    "column_counts",
    "elimination_tree",
    "symbolic_counts",
]


@numba.njit(cache=True)
def _etree(indptr, indices, perm, pinv, n):  # pragma: no cover - compiled
    """Parent of every node of the elimination tree of A[p][:, p] (−1 at roots)."""
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    for k in range(n):
        col = perm[k]
        for q in range(indptr[col], indptr[col + 1]):
            i = pinv[indices[q]]
            while i != -1 and i < k:  # climb from i towards the root, pointing every visited node at k
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    return parent


@numba.njit(cache=True)
def _postorder(parent, n):  # pragma: no cover - compiled
    """A postorder of the forest given by ``parent`` (children in increasing order)."""
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for j in range(n - 1, -1, -1):
        p = parent[j]
        if p != -1:
            nxt[j] = head[p]
            head[p] = j
    post = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    k = 0
    for root in range(n):
        if parent[root] != -1:
            continue
        top = 0
        stack[0] = root
        while top >= 0:
            p = stack[top]
            c = head[p]
            if c == -1:
                top -= 1
                post[k] = p
                k += 1
            else:
                head[p] = nxt[c]
                top += 1
                stack[top] = c
    return post


@numba.njit(cache=True)
def _colcounts(indptr, indices, perm, pinv, parent, post, n):  # pragma: no cover - compiled
    """Nonzeros of every column of L (diagonal included), see the module docstring."""
    first = np.full(n, -1, np.int64)  # postorder index of the first descendant of each node
    for k in range(n):
        j = post[k]
        while j != -1 and first[j] == -1:
            first[j] = k
            j = parent[j]
    delta = np.zeros(n, np.int64)
    haschild = np.zeros(n, np.bool_)
    for j in range(n):
        if parent[j] != -1:
            haschild[parent[j]] = True
    for j in range(n):
        if not haschild[j]:
            delta[j] = 1  # a leaf of the tree: its own row has no off-diagonal entry
    maxfirst = np.full(n, -1, np.int64)
    prevleaf = np.full(n, -1, np.int64)
    anc = np.arange(n)
    for k in range(n):
        j = post[k]
        if parent[j] != -1:
            delta[parent[j]] -= 1
        col = perm[j]
        for q in range(indptr[col], indptr[col + 1]):
            i = pinv[indices[q]]
            if i <= j or first[j] <= maxfirst[i]:
                continue  # upper part, the diagonal, or j has a descendant already seen in row i
            maxfirst[i] = first[j]
            jprev = prevleaf[i]
            prevleaf[i] = j
            delta[j] += 1
            if jprev != -1:  # the least common ancestor of the previous leaf of row i and j
                r = jprev
                while r != anc[r]:
                    r = anc[r]
                s = jprev
                while s != r:
                    t = anc[s]
                    anc[s] = r
                    s = t
                delta[r] -= 1
        if parent[j] != -1:
            anc[j] = parent[j]
    for k in range(n):
        j = post[k]
        if parent[j] != -1:
            delta[parent[j]] += delta[j]
    return delta


@numba.njit(cache=True)
def _supernodes(parent, post, counts, n):  # pragma: no cover - compiled
    """(number of fundamental supernodes, Σ rows × columns of their dense blocks, max (rows below)²)."""
    nchild = np.zeros(n, np.int64)
    for j in range(n):
        if parent[j] != -1:
            nchild[parent[j]] += 1
    nsuper = 0
    values = 0
    max_update = 0
    k = 0
    while k < n:
        j = post[k]
        rows = counts[j]
        cols = 1
        while k + cols < n:
            nxt = post[k + cols]
            prev = post[k + cols - 1]
            if parent[prev] != nxt or nchild[nxt] != 1 or counts[nxt] != counts[prev] - 1:
                break
            cols += 1
        nsuper += 1
        values += rows * cols
        below = rows - cols
        if below * below > max_update:
            max_update = below * below
        k += cols
    return nsuper, values, max_update


@dataclass(frozen=True)
class SymbolicCounts:
    """Sizes of the Cholesky factor of one pattern under one ordering (all counts, not bytes)."""

    n: int  # rows (DOFs)
    nnz_matrix: int  # stored entries of the symmetric pattern analysed (both triangles)
    nnz_factor: int  # nonzeros of L, diagonal included (exact)
    supernodes: int  # fundamental supernodes
    supernodal_values: int  # Σ rows × columns over the supernodes' dense blocks (≥ nnz_factor)
    max_update: int  # largest (rows below a supernode)², the update-block workspace of a supernodal factorisation


def _prepare(indptr, indices, n: int, perm) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    indptr = np.ascontiguousarray(indptr)
    indices = np.ascontiguousarray(indices)
    if indptr.shape != (n + 1,):
        raise ValueError(f"indptr has shape {indptr.shape}, expected ({n + 1},)")
    if perm is None:
        p = np.arange(n, dtype=np.int64)
    else:
        p = np.ascontiguousarray(perm, dtype=np.int64)
        if p.shape != (n,):
            raise ValueError(f"permutation has shape {p.shape}, expected ({n},)")
    pinv = np.full(n, -1, dtype=np.int64)
    pinv[p] = np.arange(n, dtype=np.int64)
    if n and (pinv < 0).any():
        raise ValueError("perm is not a permutation of 0..n-1")
    return indptr, indices, p, pinv


def elimination_tree(indptr, indices, n: int, perm=None) -> np.ndarray:
    """Parent of each node (in the permuted numbering) of the elimination tree of ``A[p][:, p]``; −1 at roots.

    ``indptr``/``indices``: CSR or CSC arrays of the symmetric pattern with both triangles (only the pattern is
    read; a one-triangle pattern gives a wrong tree)."""
    indptr, indices, p, pinv = _prepare(indptr, indices, n, perm)
    return _etree(indptr, indices, p, pinv, n)


def column_counts(indptr, indices, n: int, perm=None) -> np.ndarray:
    """Nonzeros of each column of the Cholesky factor of ``A[p][:, p]`` (diagonal included, permuted numbering)."""
    indptr, indices, p, pinv = _prepare(indptr, indices, n, perm)
    parent = _etree(indptr, indices, p, pinv, n)
    post = _postorder(parent, n)
    return _colcounts(indptr, indices, p, pinv, parent, post, n)


def symbolic_counts(indptr, indices, n: int, perm=None) -> SymbolicCounts:
    """Exact nnz(L) and the supernodal sizes of the Cholesky factor of ``A[p][:, p]`` (see the module docstring).

    ``perm``: the solver's fill-reducing ordering with CHOLMOD's meaning of ``p`` (None: the natural order)."""
    n = int(n)
    indptr, indices, p, pinv = _prepare(indptr, indices, n, perm)
    if n == 0:
        return SymbolicCounts(0, 0, 0, 0, 0, 0)
    parent = _etree(indptr, indices, p, pinv, n)
    post = _postorder(parent, n)
    counts = _colcounts(indptr, indices, p, pinv, parent, post, n)
    nsuper, values, max_update = _supernodes(parent, post, counts, n)
    return SymbolicCounts(
        n=n,
        nnz_matrix=int(indptr[n] - indptr[0]),
        nnz_factor=int(counts.sum()),
        supernodes=int(nsuper),
        supernodal_values=int(values),
        max_update=int(max_update),
    )


def cholesky_nnz(indptr, indices, n: int, perm=None) -> int:
    """Exact number of nonzeros of the Cholesky factor L of ``A[p][:, p]`` (diagonal included)."""
    return symbolic_counts(indptr, indices, n, perm).nnz_factor


def cholesky_flops(indptr, indices, n: int, perm=None) -> float:
    """Σ_j c_j² over the column counts c_j of the Cholesky factor of ``A[p][:, p]``: proportional to the
    floating-point work of its factorisation (the measure by which two orderings of one pattern are compared)."""
    counts = column_counts(indptr, indices, int(n), perm).astype(np.float64)
    return float(counts @ counts)
