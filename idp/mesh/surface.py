"""Boundary extraction and combinatorial surface checks (closed, manifold, oriented).

The contact layer works on the boundary of the solid, so the boundary must come out
outward-oriented and the checks must say precisely what is wrong with a surface
(open edges, non-manifold edges, flipped faces) before any simulation starts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idp.errors import MeshError
from idp.mesh.components import connected_components

# Outward faces of a positively oriented tet (a, b, c, d) = local indices (0, 1, 2, 3).
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)
# Boundary edges of a counter-clockwise triangle (interior on the left).
_TRI_EDGES = np.array([[0, 1], [1, 2], [2, 0]], dtype=np.int64)


def _unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """np.unique(rows, axis=0) with inverse and counts, using scalar keys when they fit in int64."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    m, k = rows.shape
    if m == 0:
        return rows.reshape(0, k), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    base = int(rows.max()) + 1
    if rows.min() >= 0 and base**k < 2**62:
        key = np.zeros(m, dtype=np.int64)
        for j in range(k):  # k <= 3 columns, not a loop over elements
            key = key * base + rows[:, j]
        _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        return rows[first], inverse.reshape(-1), counts
    uniq, inverse, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    return uniq, inverse.reshape(-1), counts


def _as_index_array(a: np.ndarray, name: str, widths: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim != 2 or arr.shape[1] not in widths:
        raise MeshError(f"{name} must be an (m, k) index array with k in {widths}, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise MeshError(f"{name} must hold integer indices, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def boundary_faces(elements: np.ndarray) -> np.ndarray:
    """Outward boundary of a positively oriented simplicial mesh.

    Tets ``(m, 4)`` give ``(k, 3)`` outward triangles; 2D triangles ``(m, 3)`` give ``(k, 2)``
    edges with the interior on their left. A face is on the boundary when no other element
    shares it.
    """
    elems = _as_index_array(elements, "elements", (3, 4))
    local = _TET_FACES if elems.shape[1] == 4 else _TRI_EDGES
    k = local.shape[1]
    if elems.shape[0] == 0:
        return np.zeros((0, k), dtype=np.int64)
    faces = elems[:, local].reshape(-1, k)
    _, inverse, counts = _unique_rows(np.sort(faces, axis=1))
    return np.ascontiguousarray(faces[counts[inverse] == 1])


def boundary_vertices(faces: np.ndarray) -> np.ndarray:
    """Sorted unique vertex indices used by ``faces``."""
    return np.unique(np.asarray(faces, dtype=np.int64).ravel())


def _directed_edges(faces: np.ndarray) -> np.ndarray:
    """Half-edges (f[i], f[i+1]) of polygons, or the segments themselves for (m, 2) polylines."""
    k = faces.shape[1]
    if k == 2:
        return faces
    nxt = np.roll(np.arange(k), -1)
    return np.stack([faces, faces[:, nxt]], axis=2).reshape(-1, 2)


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Sorted unique edges ``(e, 2)`` (each row ``i < j``) of a triangle surface or polyline."""
    f = _as_index_array(faces, "faces", (2, 3, 4))
    if f.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64)
    uniq, _, _ = _unique_rows(np.sort(_directed_edges(f), axis=1))
    return uniq


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Sorted edges ``(b, 2)`` of a triangle surface used by exactly one face (the open boundary)."""
    f = _as_index_array(faces, "faces", (3,))
    if f.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64)
    uniq, _, counts = _unique_rows(np.sort(_directed_edges(f), axis=1))
    return uniq[counts == 1]


@dataclass
class SurfaceTopology:
    """Combinatorial summary of a triangle surface or a 2D polyline.

    For triangle surfaces the counts are over edges. For polylines ``(m, 2)`` they are over
    vertices, the polyline analogue: a "boundary" vertex is an open end (used by one
    segment), a "non-manifold" vertex is used by more than two segments, an "inconsistent"
    vertex is used by two segments pointing the same way (both in or both out).
    """

    num_faces: int
    num_edges: int
    num_boundary_edges: int
    num_nonmanifold_edges: int
    num_inconsistent_edges: int
    num_components: int
    is_closed: bool
    is_consistently_oriented: bool

    @property
    def is_manifold(self) -> bool:
        return self.num_nonmanifold_edges == 0

    @property
    def is_closed_manifold(self) -> bool:
        """Closed, manifold and consistently oriented: what a solid's boundary must be."""
        return self.is_closed and self.is_consistently_oriented


def _count_components(edges: np.ndarray, num_vertices: int) -> int:
    """Connected components among the vertices referenced by ``edges``."""
    used = np.unique(edges.ravel())
    if used.size == 0:
        return 0
    _, labels = connected_components(num_vertices, edges[:, 0], edges[:, 1])
    return int(np.unique(labels[used]).size)


def surface_topology(faces: np.ndarray, num_vertices: int) -> SurfaceTopology:
    """Boundary / non-manifold / orientation / component counts of a surface or polyline."""
    f = _as_index_array(faces, "faces", (2, 3))
    if f.size and (f.min() < 0 or f.max() >= num_vertices):
        raise MeshError(f"face indices must lie in [0, {num_vertices}), found range [{f.min()}, {f.max()}]")
    if f.shape[0] == 0:
        return SurfaceTopology(0, 0, 0, 0, 0, 0, False, True)
    half = _directed_edges(f)
    components = _count_components(half, num_vertices)

    if f.shape[1] == 2:
        out_deg = np.bincount(f[:, 0], minlength=num_vertices)
        in_deg = np.bincount(f[:, 1], minlength=num_vertices)
        deg = out_deg + in_deg
        n_open = int(np.count_nonzero(deg == 1))
        n_nonmanifold = int(np.count_nonzero(deg > 2))
        n_inconsistent = int(np.count_nonzero((deg == 2) & (out_deg != 1)))
        n_edges = int(unique_edges(f).shape[0])
    else:
        sorted_half = np.sort(half, axis=1)
        uniq, inverse, counts = _unique_rows(sorted_half)
        # +1 when the half-edge runs low->high index, -1 otherwise; two faces agreeing on
        # orientation traverse their shared edge in opposite directions (sum 0).
        direction = np.where(half[:, 0] < half[:, 1], 1, -1)
        dir_sum = np.bincount(inverse, weights=direction, minlength=uniq.shape[0])
        n_open = int(np.count_nonzero(counts == 1))
        n_nonmanifold = int(np.count_nonzero(counts > 2))
        n_inconsistent = int(np.count_nonzero((counts == 2) & (np.abs(dir_sum) == 2)))
        n_edges = int(uniq.shape[0])

    closed = n_open == 0 and n_nonmanifold == 0
    return SurfaceTopology(
        num_faces=int(f.shape[0]),
        num_edges=n_edges,
        num_boundary_edges=n_open,
        num_nonmanifold_edges=n_nonmanifold,
        num_inconsistent_edges=n_inconsistent,
        num_components=components,
        is_closed=closed,
        is_consistently_oriented=n_inconsistent == 0,
    )


def enclosed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle surface (divergence theorem).

    For a 2D polyline ``(m, 2)`` it is the signed enclosed area (shoelace formula). Positive
    for outward-oriented (counter-clockwise in 2D) boundaries. Meaningless if not closed.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = _as_index_array(faces, "faces", (2, 3))
    if f.shape[0] == 0:
        return 0.0
    if f.shape[1] == 3:
        if v.shape[1] != 3:
            raise MeshError(f"triangle faces need (n, 3) vertices, got shape {v.shape}")
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        # Shift to the centroid to reduce cancellation for surfaces far from the origin.
        o = v[np.unique(f)].mean(axis=0)
        a, b, c = a - o, b - o, c - o
        return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)
    if v.shape[1] != 2:
        raise MeshError(f"polyline faces need (n, 2) vertices, got shape {v.shape}")
    o = v[np.unique(f)].mean(axis=0)
    p, q = v[f[:, 0]] - o, v[f[:, 1]] - o
    return float(np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]) / 2.0)
