"""Surface-preserving remeshing of a tet mesh's interior with TetGen (paper §4.5, "Mesh").

The boundary triangles of the input (faces used by one tet) go to TetGen as a piecewise linear
complex; with the ``Y`` switch TetGen adds no Steiner points on the boundary, so the new mesh
has exactly the input surface — the same vertex positions, bit for bit, and the same triangles
— and remeshing cannot create overlaps. Only the interior is re-tetrahedralised, to a
radius-edge bound (``q``) and optionally a volume bound (``a``). Every property the rest of
idp relies on is verified after meshing, not assumed: :class:`~idp.errors.MeshError` if one
fails.

Licence: TetGen is dual-licensed AGPLv3 / commercial (the ``tetgen`` Python wrapper itself is
MIT). It is therefore an optional extra, ``pip install "idp[remesh]"``, and this is the only
module of idp that imports it, lazily, inside the functions that need it.

Several closed components are fine. A cavity (a hollow solid, or one shell nested inside
another) is filled by TetGen, which does not know which side of an inner shell is solid; with
``refine_surface=False`` the filled regions are found combinatorially (they lie on the back
side of input boundary triangles) and removed. With ``refine_surface=True`` cavities are not
supported: the volume check then fails with a MeshError.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from idp.errors import MeshError, MesherUnavailableError
from idp.mesh.quality import MeshQuality, inverted_elements, mesh_quality, signed_volumes
from idp.mesh.surface import _unique_rows, boundary_faces, boundary_vertices, surface_topology

INSTALL_HINT = 'surface-preserving remeshing needs the optional mesher: pip install "idp[remesh]"'

# Face i of a tet is the one opposite vertex i, outward for a positive tet (idp.mesh.surface).
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)

#: relative tolerance of the volume check (new total volume vs input total volume)
VOLUME_RTOL = 1e-9
#: a Steiner vertex (refine_surface=True) must lie within this fraction of the input surface's bounding-box diagonal
SURFACE_RTOL = 1e-9


@dataclass
class RemeshResult:
    """A remeshed tet mesh and how it relates to the input.

    ``boundary_map`` (n_old,) int64: the new index of each old boundary vertex, -1 for old
    interior (or unused) vertices, which do not survive remeshing. ``switches`` is the TetGen
    switch string used.
    """

    vertices: np.ndarray
    elements: np.ndarray
    boundary_map: np.ndarray
    quality_before: MeshQuality
    quality_after: MeshQuality
    switches: str


def _import_tetgen() -> ModuleType:
    """The tetgen module, or MesherUnavailableError with the install hint."""
    try:
        import tetgen
    except ImportError as exc:
        raise MesherUnavailableError(INSTALL_HINT) from exc
    return tetgen


def mesher_available() -> bool:
    """True when TetGen (the ``idp[remesh]`` extra) can be imported."""
    try:
        _import_tetgen()
    except MesherUnavailableError:
        return False
    return True


def _flush_c_stdout() -> None:
    """fflush(NULL): push out text the C library buffered, so it goes where fd 1 points now."""
    with contextlib.suppress(Exception):  # no C library found (unusual platforms): nothing to flush
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence file descriptor 1: the wrapper prints 'parsing switches' / 'success' even with ``Q``.

    Works on the descriptor, not ``sys.stdout`` (which pytest or a notebook may have replaced),
    because the text comes from C++.
    """
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    _flush_c_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no descriptor 1 (closed stdout): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            try:
                yield
            finally:
                _flush_c_stdout()
                os.dup2(saved, 1)
    finally:
        os.close(saved)


@contextlib.contextmanager
def _in_scratch_dir() -> Iterator[None]:
    """Run in a throw-away working directory: on a self-intersecting surface TetGen writes
    ``tetgen-tmpfile_skipped.node/.face`` into the current directory. (Changes the process's
    working directory for the duration of the call.)"""
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="idp-tetgen-") as scratch:
        os.chdir(scratch)
        try:
            yield
        finally:
            os.chdir(cwd)


def _check_input(vertices: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, elements, outward boundary faces) of a valid input, else MeshError naming the problem."""
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(elements)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"remesh_volume needs (n, 3) vertices, got shape {v.shape}")
    if e.ndim != 2 or e.shape[1] != 4:
        raise MeshError(f"remesh_volume needs (m, 4) tetrahedra, got shape {e.shape}")
    if e.shape[0] == 0:
        raise MeshError("remesh_volume needs at least one tetrahedron")
    if not np.issubdtype(e.dtype, np.integer):
        raise MeshError(f"elements must hold integer indices, got dtype {e.dtype}")
    e = e.astype(np.int64, copy=False)
    if e.min() < 0 or e.max() >= v.shape[0]:
        raise MeshError(f"element indices must lie in [0, {v.shape[0]}), found [{e.min()}, {e.max()}]")
    if not np.all(np.isfinite(v[np.unique(e)])):
        raise MeshError("vertices used by the elements contain NaN or Inf")
    bad = inverted_elements(v, e)
    if bad.size:
        raise MeshError(
            f"{bad.size} inverted or degenerate element(s) (signed volume <= 0), first {bad[:5].tolist()}: "
            "remeshing needs a positively oriented input"
        )
    _, _, face_counts = _unique_rows(np.sort(e[:, _TET_FACES].reshape(-1, 3), axis=1))
    shared = int(np.count_nonzero(face_counts > 2))
    if shared:
        raise MeshError(f"non-manifold input: {shared} triangle(s) shared by more than two tetrahedra")
    faces = boundary_faces(e)
    topo = surface_topology(faces, v.shape[0])
    if topo.num_nonmanifold_edges:
        raise MeshError(
            f"non-manifold boundary: {topo.num_nonmanifold_edges} edge(s) used by more than two boundary "
            "triangles (tets touching along an edge)"
        )
    if topo.num_boundary_edges:
        raise MeshError(f"boundary surface is not closed: {topo.num_boundary_edges} open edge(s)")
    if topo.num_inconsistent_edges:
        raise MeshError(f"boundary surface is not consistently oriented: {topo.num_inconsistent_edges} edge(s)")
    return v, e, faces


def _num(x: float) -> str:
    """Shortest round-trip positional decimal (TetGen's switch parser takes digits and '.', no exponent)."""
    return np.format_float_positional(float(x), trim="-")


def _switches(quality: float | None, max_volume: float | None, min_dihedral: float | None, refine: bool) -> str:
    s = "p"
    if quality is not None:
        if not (np.isfinite(quality) and quality >= 1.0):
            raise ValueError(f"quality (TetGen radius-edge bound q) must be a finite number >= 1, got {quality!r}")
        s += f"q{_num(quality)}"
        if min_dihedral is not None:
            if not (np.isfinite(min_dihedral) and 0.0 <= min_dihedral < 70.0):
                raise ValueError(f"min_dihedral must be in [0, 70) degrees, got {min_dihedral!r}")
            s += f"/{_num(min_dihedral)}"
    elif min_dihedral is not None:
        raise ValueError("min_dihedral is part of TetGen's quality bound: give quality as well")
    # M: never merge nearly coplanar input triangles into one facet (nor close vertices); without it
    # TetGen puts surface Steiner points on the merged facet, off the input triangles.
    s += "M" if refine else "YM"
    if max_volume is not None:
        if not (np.isfinite(max_volume) and max_volume > 0):
            raise ValueError(f"max_volume must be a positive number, got {max_volume!r}")
        s += f"a{_num(max_volume)}"
    return s + "Q"


def _row_keys(a: np.ndarray) -> np.ndarray:
    """One opaque key per row of a float64 (k, 3) array, equal iff the rows are bitwise equal."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.dtype((np.void, 24))).reshape(-1)


def _match_points(points: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Index in ``nodes`` of each of ``points`` with bitwise-equal coordinates, -1 where none."""
    k = points.shape[0]
    if nodes.shape[0] >= k and np.array_equal(_row_keys(nodes[:k]), _row_keys(points)):
        return np.arange(k, dtype=np.int64)  # TetGen keeps the input points first, in order
    _, inverse = np.unique(np.concatenate([_row_keys(points), _row_keys(nodes)]), return_inverse=True)
    inverse = inverse.reshape(-1)
    node_of = np.full(int(inverse.max()) + 1, -1, dtype=np.int64)
    node_of[inverse[k:]] = np.arange(nodes.shape[0])
    return node_of[inverse[:k]]


def _parity(tri: np.ndarray) -> np.ndarray:
    """0/1 parity of the permutation that sorts each row: equal parity = same orientation for the same triangle."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    return ((a > b).astype(np.int64) + (a > c) + (b > c)) % 2


def _oriented_keys(tri: np.ndarray) -> np.ndarray:
    """Rows (sorted triple, parity), sorted: equal arrays iff the oriented triangle sets are equal."""
    rows = np.column_stack([np.sort(tri, axis=1), _parity(tri)])
    return np.unique(rows, axis=0) if rows.size else rows


def _remove_filled_cavities(elements: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """Drop the tets TetGen put behind input boundary triangles (cavities, gaps between nested shells).

    ``surface`` holds the input's outward boundary triangles in new indices; tets are grouped into
    regions connected across faces that are not input triangles, and a region lying on the back
    side of any input triangle is not part of the solid.
    """
    m = elements.shape[0]
    faces = elements[:, _TET_FACES].reshape(-1, 3)
    _, group, _ = _unique_rows(np.sort(np.vstack([faces, surface]), axis=1))
    g_new, g_in = group[: 4 * m], group[4 * m :]
    n_groups = int(group.max()) + 1
    count = np.bincount(g_new, minlength=n_groups)
    constrained = np.zeros(n_groups, dtype=bool)
    constrained[g_in] = True
    if not np.any(count[g_in] == 2):
        return elements  # no tet behind any input triangle: nothing was filled
    parity_in = np.zeros(n_groups, dtype=np.int64)
    parity_in[g_in] = _parity(surface)
    on_surface = constrained[g_new]
    back = on_surface & (_parity(faces) != parity_in[g_new])
    front = on_surface & ~back
    order = np.argsort(g_new, kind="stable")
    gs = g_new[order]
    pair = np.flatnonzero((gs[:-1] == gs[1:]) & ~constrained[gs[:-1]])
    t0, t1 = order[pair] // 4, order[pair + 1] // 4
    graph = sp.coo_matrix((np.ones(t0.size, dtype=np.int8), (t0, t1)), shape=(m, m))
    _, labels = connected_components(graph, directed=False)
    outside = np.zeros(int(labels.max()) + 1, dtype=bool)
    outside[labels[np.flatnonzero(back) // 4]] = True
    if np.any(outside[labels[np.flatnonzero(front) // 4]]):
        raise MeshError("TetGen's mesh has a region on both sides of the input surface (self-intersecting input?)")
    return elements[~outside[labels]]


def _steiner_off_surface(points: np.ndarray, surf_x: np.ndarray, surf_tri: np.ndarray, tol: float) -> np.ndarray:
    """Indices of ``points`` farther than ``tol`` from every triangle of the input surface."""
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    corners = surf_x[surf_tri]  # (f, 3, 3)
    centroid = corners.mean(axis=1)
    reach = float(np.linalg.norm(corners - centroid[:, None], axis=2).max()) + tol
    lists = cKDTree(centroid).query_ball_point(points, reach)
    counts = np.array([len(c) for c in lists], dtype=np.int64)
    on = np.zeros(points.shape[0], dtype=bool)
    if counts.sum() == 0:
        return np.arange(points.shape[0], dtype=np.int64)
    pid = np.repeat(np.arange(points.shape[0]), counts)
    tid = np.concatenate([np.asarray(c, dtype=np.int64) for c in lists if len(c)])
    a, b, c = corners[tid, 0], corners[tid, 1], corners[tid, 2]
    p = points[pid]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 0
    safe = np.where(ok, nn, 1.0)
    plane = np.abs(np.einsum("ij,ij->i", p - a, n)) / np.sqrt(safe)
    la = np.einsum("ij,ij->i", np.cross(c - b, p - b), n) / safe
    lb = np.einsum("ij,ij->i", np.cross(a - c, p - c), n) / safe
    lam_min = np.minimum(np.minimum(la, lb), 1.0 - la - lb)
    hit = ok & (plane <= tol) & (lam_min >= -SURFACE_RTOL)
    on[pid[hit]] = True
    return np.flatnonzero(~on)


def _tetgen_fill(
    tetgen: ModuleType,
    points: np.ndarray,
    tris: np.ndarray,
    switches: str,
    *,
    remove_cavities: bool,
    input_ids: np.ndarray,
    prefix: str = "",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TetGen's tets for the surface ``tris`` over ``points``, positively oriented, cavities emptied (when asked),
    unused nodes dropped: (nodes, tets, point index -> node). ``input_ids`` name the points in errors (the caller's
    vertex ids); ``prefix`` starts every error message (e.g. the file)."""
    try:
        with _quiet_stdout(), _in_scratch_dir():
            out = tetgen.TetGen(points, tris.astype(np.int32)).tetrahedralize(switches=switches)
    except RuntimeError as exc:
        raise MeshError(
            f"{prefix}TetGen could not tetrahedralize the boundary surface ({exc}); is it self-intersecting?"
        ) from exc
    nodes = np.asarray(out[0], dtype=np.float64)
    tets = np.asarray(out[1], dtype=np.int64).reshape(-1, 4)
    if tets.shape[0] == 0:
        raise MeshError(f"{prefix}TetGen returned no tetrahedra")
    flip = signed_volumes(nodes, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    to_new = _match_points(points, nodes)  # input point -> TetGen node
    moved = np.flatnonzero(to_new < 0)
    if moved.size:
        raise MeshError(
            f"{prefix}{moved.size} boundary vertex(es) moved or dropped by TetGen (duplicate positions?), "
            f"first input vertex {int(input_ids[moved[0]])}"
        )
    if remove_cavities:
        tets = _remove_filled_cavities(tets, to_new[tris])
    used = np.unique(tets)
    compact = np.full(nodes.shape[0], -1, dtype=np.int64)
    compact[used] = np.arange(used.size)
    nodes, tets, to_new = nodes[used], compact[tets], compact[to_new]
    if np.any(to_new < 0):
        raise MeshError(f"{prefix}a boundary vertex is not used by any tetrahedron of TetGen's mesh")
    zero = np.flatnonzero(signed_volumes(nodes, tets) == 0.0)
    if zero.size:
        raise MeshError(f"{prefix}TetGen returned {zero.size} zero-volume tetrahedra")
    return nodes, tets, to_new


def remesh_volume(
    vertices: np.ndarray,
    elements: np.ndarray,
    *,
    quality: float | None = 1.414,
    max_volume: float | None = None,
    min_dihedral: float | None = None,
    refine_surface: bool = False,
) -> RemeshResult:
    """Re-tetrahedralise the interior of a tet mesh, keeping its boundary surface exactly.

    ``quality`` is TetGen's radius-edge bound (``q``; None: no quality refinement, no interior
    Steiner points), ``min_dihedral`` an optional dihedral-angle bound in degrees added to it
    (``q…/…``), ``max_volume`` an optional volume bound per tet (``a``). With
    With ``Y`` (the default) ``max_volume`` is a target, not a guarantee: TetGen does not split a
    tet when the new point would encroach on the boundary, so tets on or near it may stay larger. With
    ``refine_surface=True`` TetGen may split boundary triangles in their own plane (no ``Y``):
    the old boundary vertices are kept and every new one lies on the input surface. ``M`` is
    always given, so nearly coplanar input triangles are never merged into one facet.

    The input must be positively oriented with a closed, manifold, consistently oriented
    boundary. The result is verified: boundary positions bitwise equal, boundary triangle set
    equal to the input's (``refine_surface=False``), all tets positive, total volume equal.
    Raises MeshError when a check fails, MesherUnavailableError without the ``idp[remesh]`` extra.
    """
    tetgen = _import_tetgen()
    v, e, faces = _check_input(vertices, elements)
    switches = _switches(quality, max_volume, min_dihedral, refine_surface)

    bverts = boundary_vertices(faces)
    local = np.full(v.shape[0], -1, dtype=np.int64)
    local[bverts] = np.arange(bverts.size)
    points = np.ascontiguousarray(v[bverts])
    tris = local[faces]
    nodes, new_e, to_new = _tetgen_fill(
        tetgen, points, tris, switches, remove_cavities=not refine_surface, input_ids=bverts
    )
    vol_in = float(signed_volumes(v, e).sum())
    vol_out = float(signed_volumes(nodes, new_e).sum())
    if abs(vol_out - vol_in) > VOLUME_RTOL * abs(vol_in):
        raise MeshError(
            f"remeshed volume {vol_out:.17g} differs from the input's {vol_in:.17g} "
            "(a cavity or nested shell filled? not supported with refine_surface=True)"
        )
    new_faces = boundary_faces(new_e)
    if refine_surface:
        new_bverts = boundary_vertices(new_faces)
        if np.setdiff1d(to_new, new_bverts).size:
            raise MeshError("an input boundary vertex is no longer on the boundary after remeshing")
        steiner = np.setdiff1d(new_bverts, to_new)
        diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        off = _steiner_off_surface(nodes[steiner], points, tris, SURFACE_RTOL * diag)
        if off.size:
            raise MeshError(f"{off.size} new boundary vertex(es) are off the input surface")
    elif not np.array_equal(_oriented_keys(new_faces), _oriented_keys(to_new[tris])):
        raise MeshError("TetGen changed the boundary triangles despite the Y switch")

    boundary_map = np.full(v.shape[0], -1, dtype=np.int64)
    boundary_map[bverts] = to_new
    if not np.array_equal(_row_keys(nodes[to_new]), _row_keys(v[bverts])):
        raise MeshError("boundary vertex positions changed during remeshing")
    return RemeshResult(
        vertices=nodes,
        elements=np.ascontiguousarray(new_e),
        boundary_map=boundary_map,
        quality_before=mesh_quality(v, e),
        quality_after=mesh_quality(nodes, new_e),
        switches=switches,
    )


def tetrahedralize_surface(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    quality: float | None = 1.414,
    max_volume: float | None = None,
    source: str = "surface",
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, tets) filling a closed, outward-oriented triangle surface, its triangles and vertex positions kept
    exactly (TetGen with ``Y``; a deformable body from an OBJ/STL/PLY, e.g. the authors' rhododendron.obj, whose
    tet mesh is missing). Several components are fine; a component nested in another, wound inwards, is a cavity.
    The result is verified as :func:`remesh_volume`'s: same boundary triangles, positive tets, volume equal to the
    surface's enclosed volume. MeshError naming ``source`` when the surface is unusable."""
    from idp.mesh.surface import enclosed_volume

    tetgen = _import_tetgen()
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise MeshError(f"{source}: tetrahedralizing needs a 3D triangle surface, got {v.shape} / {f.shape}")
    f = f.astype(np.int64, copy=False)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"{source}: vertices contain NaN or Inf")
    topo = surface_topology(f, v.shape[0])
    if topo.num_boundary_edges or topo.num_nonmanifold_edges or topo.num_inconsistent_edges:
        raise MeshError(
            f"{source}: a closed, manifold, consistently oriented surface is needed to fill it with tets "
            f"({topo.num_boundary_edges} open, {topo.num_nonmanifold_edges} non-manifold, "
            f"{topo.num_inconsistent_edges} inconsistent edge(s))"
        )
    vol_in = float(enclosed_volume(v, f))
    if vol_in <= 0.0:
        raise MeshError(f"{source}: the surface encloses a non-positive volume ({vol_in:.3g}): is it wound inwards?")
    used = np.unique(f)
    local = np.full(v.shape[0], -1, dtype=np.int64)
    local[used] = np.arange(used.size)
    points = np.ascontiguousarray(v[used])
    tris = local[f]
    switches = _switches(quality, max_volume, None, False)
    nodes, tets, to_new = _tetgen_fill(
        tetgen, points, tris, switches, remove_cavities=True, input_ids=used, prefix=f"{source}: "
    )
    vol_out = float(signed_volumes(nodes, tets).sum())
    if abs(vol_out - vol_in) > VOLUME_RTOL * abs(vol_in):
        raise MeshError(f"{source}: the tets' volume {vol_out:.17g} differs from the enclosed volume {vol_in:.17g}")
    if not np.array_equal(_oriented_keys(boundary_faces(tets)), _oriented_keys(to_new[tris])):
        raise MeshError(f"{source}: TetGen changed the surface triangles despite the Y switch")
    return nodes, np.ascontiguousarray(tets)
