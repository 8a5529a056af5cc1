"""Validation of 3D triangle surfaces that deform as shells (normal flow, paper §7.2).

A shell driven along its normals needs a well-defined outward direction everywhere: every edge
shared by at most two faces, neighbouring faces wound consistently, no zero-area faces (no
normal) and finite coordinates.  ``check_shell_surface`` raises a ``MeshError`` naming the file
and the offending vertex / face / edge ids, and otherwise returns a ``ShellSurfaceInfo`` summary
(components, boundary loops, Euler characteristic, outward orientation of closed surfaces).
``degenerate_triangles`` is the cheap per-frame test used to *report* collapsed shell triangles.

Everything is vectorised; edges are keyed by their sorted vertex pair with the helpers of
``idp.mesh.surface`` (``surface_topology`` itself only counts, it does not name the elements).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from idp.errors import MeshError
from idp.mesh.components import connected_components
from idp.mesh.differential import face_area_normals
from idp.mesh.surface import _count_components, _directed_edges, _unique_rows

log = logging.getLogger("idp")

_LISTED = 5  # offending elements named per problem (the total count is always given)


@dataclass
class ShellSurfaceInfo:
    """Summary of a surface that passed ``check_shell_surface``.

    ``euler_characteristic`` is V - E + F over the referenced vertices.  ``outward`` is None
    unless the surface is closed; then it is True when every face-connected component encloses
    a positive signed volume (faces wound counter-clockwise seen from outside).
    ``enclosed_volumes`` holds that signed volume per component (empty unless closed).
    ``num_boundary_loops`` counts the connected components of the boundary edges (two loops
    touching at a bow-tie vertex count as one).
    """

    num_vertices: int
    num_faces: int
    num_edges: int
    num_components: int
    num_boundary_edges: int
    num_boundary_loops: int
    is_closed: bool
    euler_characteristic: int
    num_unreferenced_vertices: int
    num_nonmanifold_vertices: int
    outward: bool | None
    enclosed_volumes: tuple[float, ...] = ()


def _ids(idx: np.ndarray) -> str:
    """'[a, b, c, ...] (N in total)' for the first few of ``idx``."""
    idx = np.asarray(idx).ravel()
    shown = ", ".join(str(int(i)) for i in idx[:_LISTED])
    more = ", ..." if idx.size > _LISTED else ""
    return f"[{shown}{more}] ({idx.size} in total)"


def _group_members(inverse: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order, starts): rows of group g are ``order[starts[g] : starts[g] + counts[g]]``."""
    order = np.argsort(inverse, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return order, starts


def degenerate_triangles(x: np.ndarray, faces: np.ndarray, rel_tol: float = 1e-10) -> np.ndarray:
    """Sorted ids of the triangles with area ≤ rel_tol · (longest edge)², non-finite ones included.

    Scale-free per triangle, so it flags slivers and collapsed triangles in any frame; meant to
    *report* degenerate shell triangles (whose normal is undefined), not to reject a frame.
    ``x`` is (n, 3) or flat (n·3,).
    """
    X = np.asarray(x, dtype=np.float64)
    if X.ndim == 1:
        X = X.reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64)
    if X.ndim != 2 or X.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"need (n, 3) positions and (m, 3) faces, got {X.shape} and {F.shape}")
    if F.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    p = X[F]
    longest2 = np.max(np.sum((p - np.roll(p, -1, axis=1)) ** 2, axis=2), axis=1)
    area = np.linalg.norm(face_area_normals(X, F), axis=1)
    return np.flatnonzero(~(area > rel_tol * longest2))


def _check_arrays(vertices: np.ndarray, faces: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Shapes, finiteness and index validity: the problems after which nothing else can be computed."""
    X = np.asarray(vertices)
    F = np.asarray(faces)
    if X.ndim != 2 or X.shape[1] != 3:
        raise MeshError(f"{source}: shell vertices must be an (n, 3) array, got shape {X.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"{source}: shell faces must be an (m, 3) triangle array, got shape {F.shape}")
    if F.shape[0] == 0:
        raise MeshError(f"{source}: the shell surface has no faces")
    if not np.issubdtype(F.dtype, np.integer):
        raise MeshError(f"{source}: faces must hold integer vertex indices, got dtype {F.dtype}")
    if not np.issubdtype(X.dtype, np.number) or np.issubdtype(X.dtype, np.complexfloating):
        raise MeshError(f"{source}: vertices must be real numbers, got dtype {X.dtype}")
    X = X.astype(np.float64, copy=False)
    F = F.astype(np.int64, copy=False)
    bad = np.flatnonzero(~np.all(np.isfinite(X), axis=1))
    if bad.size:
        raise MeshError(f"{source}: non-finite (NaN / inf) coordinates at vertices {_ids(bad)}")
    n = X.shape[0]
    bad = np.flatnonzero(np.any((F < 0) | (F >= n), axis=1))
    if bad.size:
        raise MeshError(f"{source}: faces {_ids(bad)} index vertices outside [0, {n})")
    bad = np.flatnonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0]))
    if bad.size:
        raise MeshError(f"{source}: faces {_ids(bad)} repeat a vertex")
    return X, F


def _nonmanifold_vertices(F: np.ndarray, edge_of: np.ndarray, counts: np.ndarray, n: int) -> np.ndarray:
    """Vertices whose faces form more than one edge-connected fan (bow-ties); edges used ≤ 2 times.

    Nodes are corners (face, vertex); the two faces of an edge link their corners at both of
    the edge's vertices; a vertex's fans are the components among its corners.
    """
    m = F.shape[0]
    order, starts = _group_members(edge_of, counts)
    two = np.flatnonzero(counts == 2)
    h1, h2 = order[starts[two]], order[starts[two] + 1]  # half-edges h = 3 f + c, running F[f,c] -> F[f,c+1]
    f1, c1, f2, c2 = h1 // 3, h1 % 3, h2 // 3, h2 % 3
    # corner id 3 f + c; find in face f2 the corners holding the vertices of corner c1 and c1+1 of f1
    va, vb = F[f1, c1], F[f1, (c1 + 1) % 3]
    a2 = np.where(F[f2, c2] == va, c2, (c2 + 1) % 3)
    b2 = np.where(F[f2, c2] == vb, c2, (c2 + 1) % 3)
    rows = np.concatenate([3 * f1 + c1, 3 * f1 + (c1 + 1) % 3])
    cols = np.concatenate([3 * f2 + a2, 3 * f2 + b2])
    _, labels = connected_components(3 * m, rows, cols)
    vertex_of_label = np.zeros(labels.max() + 1, dtype=np.int64)
    vertex_of_label[labels] = F.ravel()
    fans = np.bincount(vertex_of_label, minlength=n)
    return np.flatnonzero(fans > 1)


def check_shell_surface(
    vertices: np.ndarray, faces: np.ndarray, source: str = "<array>", *, area_tol: float = 1e-12
) -> ShellSurfaceInfo:
    """Check that a 3D triangle surface has a well-defined normal field for shell deformation.

    Raises ``MeshError`` (naming ``source`` and the first offending ids with the total count) for
    non-finite coordinates, out-of-range or repeated face indices, and then, all reported in one
    message: duplicate faces, non-manifold edges (> 2 faces), inconsistent winding (an edge run in
    the same direction by its two faces, so "outward" flips across it) and zero-area faces (area ≤
    ``area_tol`` · mean edge length²).  Non-manifold vertices (bow-ties) only log a warning.
    """
    X, F = _check_arrays(vertices, faces, source)
    n, m = X.shape[0], F.shape[0]
    problems: list[str] = []

    _, face_key, face_counts = _unique_rows(np.sort(F, axis=1))
    dup_groups = np.flatnonzero(face_counts > 1)
    if dup_groups.size:
        order, starts = _group_members(face_key, face_counts)
        shown = "; ".join(
            "faces " + ", ".join(str(int(f)) for f in order[starts[g] : starts[g] + face_counts[g]])
            for g in dup_groups[:_LISTED]
        )
        more = "; ..." if dup_groups.size > _LISTED else ""
        problems.append(f"{dup_groups.size} sets of duplicate faces (same three vertices): {shown}{more}")

    half = _directed_edges(F)  # (3m, 2), half-edge h = 3 f + c runs F[f, c] -> F[f, c+1]
    edges, edge_of, counts = _unique_rows(np.sort(half, axis=1))
    order, starts = _group_members(edge_of, counts)

    def describe(es: np.ndarray) -> str:
        parts = []
        for e in es[:_LISTED]:  # message text for the few listed edges only
            fs = ", ".join(str(int(h) // 3) for h in order[starts[e] : starts[e] + counts[e]])
            parts.append(f"edge ({int(edges[e, 0])}, {int(edges[e, 1])}) in faces {fs}")
        return "; ".join(parts) + ("; ..." if es.size > _LISTED else "")

    nonmanifold = np.flatnonzero(counts > 2)
    if nonmanifold.size:
        problems.append(
            f"{nonmanifold.size} non-manifold edges (shared by more than two faces): {describe(nonmanifold)}"
        )
    direction = np.where(half[:, 0] < half[:, 1], 1, -1)
    dir_sum = np.bincount(edge_of, weights=direction, minlength=edges.shape[0])
    flipped = np.flatnonzero((counts == 2) & (np.abs(dir_sum) == 2))
    if flipped.size:
        problems.append(
            f"{flipped.size} edges with inconsistent winding (both faces run the edge the same way, "
            f"so the flow direction is undefined): {describe(flipped)}"
        )

    edge_len = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
    area = np.linalg.norm(face_area_normals(X, F), axis=1)
    zero = np.flatnonzero(area <= area_tol * float(edge_len.mean()) ** 2)
    if zero.size:
        problems.append(f"{zero.size} zero-area faces (no normal): faces {_ids(zero)}")

    if problems:
        raise MeshError(f"{source}: not a valid shell surface: " + " | ".join(problems))

    # --- summary of a valid surface
    used = np.zeros(n, dtype=bool)
    used[F.ravel()] = True
    num_used = int(np.count_nonzero(used))
    boundary = counts == 1
    num_boundary = int(np.count_nonzero(boundary))
    loops = _count_components(edges[boundary], n) if num_boundary else 0

    interior = np.flatnonzero(counts == 2)
    fa, fb = order[starts[interior]] // 3, order[starts[interior] + 1] // 3
    num_components, comp = connected_components(m, fa, fb)

    bowties = _nonmanifold_vertices(F, edge_of, counts, n)
    if bowties.size:
        log.warning(
            "%s: %d non-manifold vertices (bow-ties: face fans meeting only at the vertex; their normals "
            "average unrelated sheets): vertices %s",
            source,
            bowties.size,
            _ids(bowties),
        )

    closed = num_boundary == 0
    outward: bool | None = None
    volumes: tuple[float, ...] = ()
    if closed:
        # signed volume per component about the component's mean corner (less cancellation far from 0)
        p = X[F]  # (m, 3, 3)
        w = np.bincount(comp, minlength=num_components).astype(np.float64)
        origin = np.stack(
            [np.bincount(comp, weights=p[:, :, k].mean(axis=1), minlength=num_components) / w for k in range(3)],
            axis=1,
        )
        q = p - origin[comp][:, None, :]
        six_vol = np.einsum("ij,ij->i", q[:, 0], np.cross(q[:, 1], q[:, 2]))
        vol = np.bincount(comp, weights=six_vol, minlength=num_components) / 6.0
        volumes = tuple(float(v) for v in vol)
        outward = bool(np.all(vol > 0))

    return ShellSurfaceInfo(
        num_vertices=n,
        num_faces=m,
        num_edges=int(edges.shape[0]),
        num_components=int(num_components),
        num_boundary_edges=num_boundary,
        num_boundary_loops=int(loops),
        is_closed=closed,
        euler_characteristic=num_used - int(edges.shape[0]) + m,
        num_unreferenced_vertices=n - num_used,
        num_nonmanifold_vertices=int(bowties.size),
        outward=outward,
        enclosed_volumes=volumes,
    )


__all__ = ["ShellSurfaceInfo", "check_shell_surface", "degenerate_triangles"]
