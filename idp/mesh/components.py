"""Connected components of an undirected graph given by its edges (union-find, compiled).

The surface checks of every run's input count components (boundary loops, face fans, surface parts). scipy's
``scipy.sparse.csgraph.connected_components`` did that, but importing ``scipy.sparse.csgraph`` also imports
``scipy.sparse.linalg`` and ``scipy.linalg`` (≈ 11 MB of resident memory and ≈ 0.1–0.2 s at start-up, issue
16) for one call; a run needs neither.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["connected_components"]


@numba.njit(cache=True)
def _component_labels(n, a, b, labels):  # pragma: no cover - compiled
    """labels[v] = component of vertex v (0, 1, … in the order of each component's smallest vertex) of the graph on
    n vertices with edges (a[k], b[k]); returns the number of components. Union by smaller root, path halving."""
    parent = np.arange(n)
    for k in range(a.size):
        u, v = a[k], b[k]
        while parent[u] != u:
            parent[u] = parent[parent[u]]
            u = parent[u]
        while parent[v] != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        if u < v:
            parent[v] = u
        elif v < u:
            parent[u] = v
    count = 0
    for v in range(n):
        r = v
        while parent[r] != r:
            r = parent[r]
        if r == v:
            labels[v] = count
            count += 1
        else:
            labels[v] = labels[r]  # r < v: already labelled
    return count


def connected_components(num_vertices: int, a: np.ndarray, b: np.ndarray) -> tuple[int, np.ndarray]:
    """(number of components, label per vertex) of the undirected graph on ``num_vertices`` vertices with edges
    (a[k], b[k]); isolated vertices are components of their own, as in scipy's ``connected_components``."""
    labels = np.empty(num_vertices, dtype=np.int64)
    count = _component_labels(
        int(num_vertices),
        np.ascontiguousarray(a, dtype=np.int64).ravel(),
        np.ascontiguousarray(b, dtype=np.int64).ravel(),
        labels,
    )
    return int(count), labels
