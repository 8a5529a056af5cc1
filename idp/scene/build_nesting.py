"""Deformable bodies that start one inside another (their surfaces need not cross: a small copy in a big one).

The input check of :mod:`idp.scene.build` finds crossing surfaces. A body lying wholly inside another
body's elements crosses nothing, yet the two overlap from the start; with no crossing, one vertex of the inner
body inside the outer body's elements is enough to tell (a body in a cavity of a hollow mesh is not inside).
"""

from __future__ import annotations

import numpy as np

from idp.output.parts import Part

#: barycentric slack: a vertex this close to an element's face (relative) counts as inside it
_SLACK = 1e-12


def point_in_simplices(q: np.ndarray, x: np.ndarray, elements: np.ndarray) -> bool:
    """Whether the point ``q`` (d,) lies in one of the simplices ``elements`` (m, d+1) of ``x`` (closed)."""
    p = x[elements]  # (m, d+1, d)
    near = np.all((p.min(axis=1) <= q) & (q <= p.max(axis=1)), axis=1)
    p = p[near]
    if p.shape[0] == 0:
        return False
    edges = np.swapaxes(p[:, 1:] - p[:, :1], 1, 2)  # (m, d, d): columns p_i - p_0
    ok = np.abs(np.linalg.det(edges)) > 0
    if not ok.any():
        return False
    lam = np.linalg.solve(edges[ok], (q - p[ok, 0])[:, :, None])[:, :, 0]
    bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
    return bool(np.any(np.all(bary >= -_SLACK, axis=1)))


def nested_bodies(x: np.ndarray, parts: list[Part]) -> list[tuple[str, str]]:
    """``(inner, outer)`` names of deformable bodies with a vertex inside another's elements, when the inner
    body's bounding box lies inside the outer's. Meaningful once no surfaces cross (then inner lies wholly
    inside outer)."""
    bodies = [p for p in parts if p.kind == "deformable" and p.elements is not None and p.vertex_ids.size]
    if len(bodies) < 2:
        return []
    lo = np.stack([x[p.vertex_ids].min(axis=0) for p in bodies])
    hi = np.stack([x[p.vertex_ids].max(axis=0) for p in bodies])
    found: list[tuple[str, str]] = []
    for a, inner in enumerate(bodies):
        inside = np.all((lo <= lo[a]) & (hi[a] <= hi), axis=1)
        inside[a] = False
        q = x[inner.vertex_ids[0]]
        for b in np.flatnonzero(inside):
            outer = bodies[int(b)]
            assert outer.elements is not None
            if point_in_simplices(q, x, outer.elements):
                found.append((inner.name, outer.name))
    return found
