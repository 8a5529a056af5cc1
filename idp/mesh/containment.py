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
