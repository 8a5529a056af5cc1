"""Hinge stencils of a triangle mesh: one per interior edge, for discrete-shell bending."""

from __future__ import annotations

from typing import Literal, overload

import numpy as np
import numpy.typing as npt


@overload
def triangle_hinges(triangles: npt.ArrayLike, return_faces: Literal[False] = False) -> np.ndarray: ...


@overload
def triangle_hinges(triangles: npt.ArrayLike, return_faces: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...


def triangle_hinges(triangles: npt.ArrayLike, return_faces: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """(h, 4) hinges [x0, x1, x2, x3] of the interior edges (edges with exactly two faces).

    x0–x1 is the shared edge, in the winding order of the first face (x0, x1, x2); x3 is the vertex of
    the second face opposite the edge.  For a consistently oriented mesh the second face is (x1, x0, x3),
    so both faces' normals are the ones the bending kernel uses.  Boundary edges give no hinge; an edge
    with more than two faces (non-manifold) raises ValueError naming it.  With ``return_faces`` also the
    (h, 2) face indices.  Hinges are ordered by their (min, max) edge key."""
    T = np.asarray(triangles, dtype=np.int64)
    if T.ndim != 2 or T.shape[1] != 3:
        raise ValueError(f"triangles must be (m, 3), got shape {T.shape}")
    m = T.shape[0]
    # half-edge (face f, corner c): edge T[f, c] -> T[f, c+1], opposite vertex T[f, c+2]
    src = T.reshape(-1)
    dst = T[:, [1, 2, 0]].reshape(-1)
    opp = T[:, [2, 0, 1]].reshape(-1)
    face = np.repeat(np.arange(m), 3)
    lo = np.minimum(src, dst)
    hi = np.maximum(src, dst)
    order = np.lexsort((face, hi, lo))
    lo, hi = lo[order], hi[order]
    if lo.size == 0:
        empty = np.zeros((0, 4), dtype=np.int64)
        return (empty, np.zeros((0, 2), dtype=np.int64)) if return_faces else empty
    start = np.flatnonzero(np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])])
    count = np.diff(np.r_[start, lo.size])
    over = np.flatnonzero(count > 2)
    if over.size:
        s = start[over[0]]
        raise ValueError(
            f"edge ({int(lo[s])}, {int(hi[s])}) has {int(count[over[0]])} faces; "
            "hinges need a manifold mesh (at most two faces per edge)"
        )
    first = order[start[count == 2]]
    second = order[start[count == 2] + 1]
    hinges = np.stack([src[first], dst[first], opp[first], opp[second]], axis=1)
    if return_faces:
        return hinges, np.stack([face[first], face[second]], axis=1)
    return hinges
