"""Per-element signed volumes and the inverted / degenerate element queries built on them.

Every layer that needs orientation (file loading, checks, the injectivity certificate) goes
through :func:`signed_volumes`, so the sign convention lives in one place: a tetrahedron
``(a, b, c, d)`` is positive when ``det[b-a, c-a, d-a] > 0`` and a triangle ``(a, b, c)`` in
2D is positive when it is counter-clockwise.
"""

from __future__ import annotations

import numpy as np

from idp.errors import MeshError


def _check_simplices(vertices: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (vertices float64, elements int64) after checking that they describe simplices."""
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(elements)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise MeshError(f"vertices must be an (n, 2) or (n, 3) array, got shape {v.shape}")
    d = v.shape[1]
    if e.ndim != 2 or e.shape[1] != d + 1:
        raise MeshError(f"elements must be an (m, {d + 1}) array for {d}D vertices, got shape {e.shape}")
    return v, e.astype(np.int64, copy=False)


def signed_volumes(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron (``det/6``) or signed area of each 2D triangle (``det/2``)."""
    v, e = _check_simplices(vertices, elements)
    if e.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    x0 = v[e[:, 0]]
    if v.shape[1] == 3:
        a = v[e[:, 1]] - x0
        b = v[e[:, 2]] - x0
        c = v[e[:, 3]] - x0
        return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    a = v[e[:, 1]] - x0
    b = v[e[:, 2]] - x0
    return (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) / 2.0


def inverted_elements(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Indices (int64) of elements whose signed volume is <= 0."""
    return np.flatnonzero(signed_volumes(vertices, elements) <= 0.0).astype(np.int64)


def degenerate_elements(vertices: np.ndarray, elements: np.ndarray, rel_tol: float = 1e-12) -> np.ndarray:
    """Indices (int64) of elements with ``|volume| <= rel_tol * mean |volume|``.

    The threshold is relative so the test does not depend on the mesh's units. When every
    element has zero volume, all of them are degenerate.
    """
    vol = np.abs(signed_volumes(vertices, elements))
    if vol.size == 0:
        return np.zeros(0, dtype=np.int64)
    threshold = rel_tol * float(vol.mean())
    return np.flatnonzero(vol <= threshold).astype(np.int64)
