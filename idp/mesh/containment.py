"""Generalized winding numbers: is a point inside a closed, outward-oriented boundary (3D triangles, 2D segments)?

Two closed surfaces that do not cross are either apart or one holds the other. The surface intersection check
of the start state cannot tell a body placed *inside another body's material* (an instance dropped into a
dumpling, a tool started inside the dough) from one placed beside it; the winding number of one vertex can:
w = 1 inside a body's material, 0 outside (also inside a cavity: the cavity's inward-facing boundary cancels).
"""

from __future__ import annotations

import numpy as np


def winding_numbers(points: np.ndarray, vertices: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(k,) winding numbers of ``points`` (k,d) w.r.t. the closed boundary ``cells`` (triangles in 3D, segments
    in 2D, outward-oriented) over ``vertices`` (n,d). Points on the boundary give values between 0 and 1."""
    P = np.asarray(points, dtype=np.float64)
    V = np.asarray(vertices, dtype=np.float64)
    C = np.asarray(cells, dtype=np.int64)
    out = np.zeros(P.shape[0])
    if C.size == 0:
        return out
    if V.shape[1] == 2:
        for i, p in enumerate(P):  # one vectorised pass over the segments per query point
            a, b = V[C[:, 0]] - p, V[C[:, 1]] - p
            cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
            dot = (a * b).sum(axis=1)
            out[i] = np.arctan2(cross, dot).sum() / (2.0 * np.pi)
        return out
    for i, p in enumerate(P):  # solid angle of each triangle (Van Oosterom & Strackee)
        a, b, c = V[C[:, 0]] - p, V[C[:, 1]] - p, V[C[:, 2]] - p
        la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(1) * lc + (b * c).sum(1) * la + (c * a).sum(1) * lb
        out[i] = 2.0 * np.arctan2(det, den).sum() / (4.0 * np.pi)
    return out


_AXES = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])


def shielded(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(k,) bool: whether every ray from a point along ±x, ±y, ±z hits a triangle of ``triangles`` (3D).

    A body held in another's cavity (a dumpling's filling in its wrapper) is outside that body's material
    (winding number 0) but shielded on all sides: hidden from a viewer outside. Möller–Trumbore ray–triangle
    tests, vectorised over the triangles."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.ones(P.shape[0], dtype=bool)
    for d in _AXES:
        pvec = np.cross(d, e2)  # (m,3)
        det = np.einsum("ij,ij->i", e1, pvec)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        for i in np.flatnonzero(out):
            s = P[i] - a
            u = np.einsum("ij,ij->i", s, pvec) * inv
            q = np.cross(s, e1)
            v = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
            out[i] = bool(hit.any())
    return out
