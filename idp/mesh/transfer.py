"""Carry per-element data from one simplicial mesh to another covering the same region (after remeshing).

Each new element takes the value of the old element that contains its centroid
(:func:`locate_points`). Rest frames are transferred so that the deformation gradient is kept:
a new element gets the old element's F, which keeps stress and elastic energy density piecewise
the same across a remesh (paper §4.5, remeshing at the end of a time step). Works for tets in 3D
and triangles in 2D; no mesher is needed.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial import cKDTree

from idp.errors import MeshError

#: a query point counts as inside an element when all its barycentric coordinates are >= -this
INSIDE_TOL = 1e-10


def _mesh(x: np.ndarray, elements: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(x, dtype=np.float64)
    e = np.asarray(elements)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise MeshError(f"{name} vertices must be (n, 2) or (n, 3), got shape {v.shape}")
    if e.ndim != 2 or e.shape[1] != v.shape[1] + 1:
        raise MeshError(f"{name} elements must be (m, {v.shape[1] + 1}), got shape {e.shape}")
    if e.size and not np.issubdtype(e.dtype, np.integer):
        raise MeshError(f"{name} elements must hold integer indices, got dtype {e.dtype}")
    e = e.astype(np.int64, copy=False)
    if e.size and (e.min() < 0 or e.max() >= v.shape[0]):
        raise MeshError(f"{name} element indices must lie in [0, {v.shape[0]}), found [{e.min()}, {e.max()}]")
    if not np.all(np.isfinite(v)):
        raise MeshError(f"{name} vertices contain NaN or Inf")
    return v, e


def _edge_matrices(v: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(m, d, d) matrices with columns x_a - x_0 (the Ds / Dm convention of idp.energies.elastic)."""
    xe = v[e]
    return np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1))


def _locate(old_x: np.ndarray, old_elements: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
    """Element per point — see :func:`locate_points`."""
    m = old_elements.shape[0]
    q = points.shape[0]
    if m == 0:
        raise MeshError("cannot locate points in a mesh with no elements")
    centroids = old_x[old_elements].mean(axis=1)
    Ds = _edge_matrices(old_x, old_elements)
    if np.any(np.abs(np.linalg.det(Ds)) == 0.0):
        raise MeshError("cannot locate points in a mesh with zero-volume elements")
    Ds_inv = np.linalg.inv(Ds)
    tree = cKDTree(centroids)
    best = np.zeros(q, dtype=np.int64)
    score = np.full(q, -np.inf)  # the smallest barycentric coordinate in the best candidate so far
    todo = np.arange(q)
    kk = min(k, m)
    tried = 0
    while todo.size:
        _, cand = tree.query(points[todo], k=kk)
        cand = np.asarray(cand, dtype=np.int64).reshape(todo.size, kk)
        for j in range(tried, kk):  # loop over the candidate rank, vectorised over points
            c = cand[:, j]
            lam = np.einsum("qab,qb->qa", Ds_inv[c], points[todo] - old_x[old_elements[c, 0]])
            lam_min = np.minimum(lam.min(axis=1), 1.0 - lam.sum(axis=1))
            better = lam_min > score[todo]
            best[todo[better]] = c[better]
            score[todo[better]] = lam_min[better]
        tried = kk
        if kk == m:
            break
        todo = todo[score[todo] < -INSIDE_TOL]  # not yet found inside: look further out
        kk = min(4 * kk, m, max(64, k))
        if kk == tried:
            break
    return best


def locate_points(old_x: np.ndarray, old_elements: np.ndarray, points: np.ndarray, *, k: int = 8) -> np.ndarray:
    """(q,) index of the old element containing each query point.

    Candidates are the ``k`` elements with the nearest centroids (scipy cKDTree), then exact
    barycentric tests; points not found inside are retried with more candidates (up to
    max(64, k)). A point outside every candidate (outside the mesh, or by round-off on its
    boundary) gets the candidate it is least outside of (largest smallest barycentric
    coordinate), which for a point just off the boundary is the element it is next to.
    """
    v, e = _mesh(old_x, old_elements, "old")
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != v.shape[1]:
        raise MeshError(f"points must be (q, {v.shape[1]}), got shape {p.shape}")
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    if p.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    return _locate(v, e, p, k)


def _locate_new_centroids(
    old_x: np.ndarray, old_elements: np.ndarray, new_x: np.ndarray, new_elements: np.ndarray
) -> np.ndarray:
    v_old, e_old = _mesh(old_x, old_elements, "old")
    v_new, e_new = _mesh(new_x, new_elements, "new")
    if v_old.shape[1] != v_new.shape[1]:
        raise MeshError(f"old and new meshes differ in dimension ({v_old.shape[1]} and {v_new.shape[1]})")
    if e_new.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    return locate_points(v_old, e_old, v_new[e_new].mean(axis=1))


def transfer_rest_frames(
    old_x: np.ndarray,
    old_elements: np.ndarray,
    old_rest_frames: np.ndarray,
    new_x: np.ndarray,
    new_elements: np.ndarray,
) -> np.ndarray:
    """Rest frames Dm (m', d, d) for the new mesh that keep each element's deformation gradient.

    ``old_x`` / ``new_x`` are the *current* positions of the two meshes (the new mesh covers the
    old one's current shape), ``old_rest_frames`` the old effective rest frames Dm (m, d, d) with
    columns X_a - X_0, as :attr:`ElasticEnergy.base_rest_frames` (times the rest transform, if
    any). A new element whose centroid lies in old element e gets F_e = Ds_e Dm_e⁻¹ and the rest
    frame Dm_new = F_e⁻¹ Ds_new, so that Ds_new Dm_new⁻¹ = F_e. det Dm_new > 0 when both meshes
    are positively oriented and the old rest frames are.
    """
    v_old, e_old = _mesh(old_x, old_elements, "old")
    v_new, e_new = _mesh(new_x, new_elements, "new")
    d = v_old.shape[1]
    dm = np.asarray(old_rest_frames, dtype=np.float64)
    if dm.shape != (e_old.shape[0], d, d):
        raise MeshError(f"old_rest_frames must have shape ({e_old.shape[0]}, {d}, {d}), got {dm.shape}")
    loc = _locate_new_centroids(v_old, e_old, v_new, e_new)
    ds_old = _edge_matrices(v_old, e_old)
    # F⁻¹ = Dm Ds⁻¹, i.e. (Ds⁻ᵀ Dmᵀ)ᵀ, solved rather than inverted
    f_inv = np.transpose(np.linalg.solve(np.transpose(ds_old, (0, 2, 1)), np.transpose(dm, (0, 2, 1))), (0, 2, 1))
    return np.ascontiguousarray(f_inv[loc] @ _edge_matrices(v_new, e_new))


def transfer_cell_data(
    old_x: np.ndarray,
    old_elements: np.ndarray,
    new_x: np.ndarray,
    new_elements: np.ndarray,
    arrays: Mapping[str, np.ndarray],
) -> dict[str, np.ndarray]:
    """Per-element arrays (m, ...) carried to the new mesh piecewise-constantly: each new element
    takes the value of the old element containing its centroid (current positions)."""
    v_old, e_old = _mesh(old_x, old_elements, "old")
    m = e_old.shape[0]
    for name, arr in arrays.items():
        if np.shape(arr)[:1] != (m,):
            raise MeshError(f"cell array {name!r} must have one row per old element ({m}), got shape {np.shape(arr)}")
    loc = _locate_new_centroids(v_old, e_old, new_x, new_elements)
    return {name: np.asarray(arr)[loc] for name, arr in arrays.items()}
