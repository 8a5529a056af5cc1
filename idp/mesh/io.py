"""Reading and writing mesh files, with validation that names the file and the bad entries.

``read_mesh`` returns a positively oriented :class:`VolumeMesh` (tets in 3D, triangles in
2D) or a :class:`SurfaceMesh`. Everything the solver relies on (finite coordinates, valid
indices, consistent positive orientation, no degenerate elements) is checked here once, so
later layers can assume it.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from idp.errors import MeshError
from idp.fs import is_file, why
from idp.mesh.obj import read_obj
from idp.mesh.quality import signed_volumes
from idp.mesh.surface import boundary_faces
from idp.mesh.types import SurfaceMesh, VolumeMesh

logger = logging.getLogger("idp")

_KINDS = ("auto", "volume", "surface")
# Formats that only ever hold surfaces: planar triangles there are a flat surface, not a 2D solid.
_SURFACE_ONLY_EXTS = (".obj", ".stl", ".ply", ".off")
_TET_TYPES = ("tetra", "tetra10")
_TRI_TYPES = ("triangle", "triangle6", "triangle7")
_LINE_TYPES = ("line", "line3")
_MAX_LISTED = 10


def _list(indices: np.ndarray) -> str:
    """First few indices as text, with an ellipsis when there are more."""
    shown = ", ".join(str(int(i)) for i in indices[:_MAX_LISTED])
    return shown + (", ..." if indices.size > _MAX_LISTED else "")


def _read_meshio(path: Path):
    """meshio.read with its failures turned into MeshError.

    On a file it cannot parse, meshio prints the reason and calls ``sys.exit``; capture the
    printout and the exit so the message can name the file and the cause instead.
    """
    import contextlib
    import io as _io
    import warnings

    import meshio

    captured = _io.StringIO()
    try:
        with contextlib.redirect_stdout(captured), contextlib.redirect_stderr(captured), warnings.catch_warnings():
            # meshio's STL format sniffing overflows harmlessly on ASCII files.
            warnings.simplefilter("ignore", RuntimeWarning)
            return meshio.read(str(path))
    except (Exception, SystemExit) as exc:  # meshio raises many types, or exits
        detail = " ".join(captured.getvalue().split())
        reason = f"{type(exc).__name__}: {exc}" if not isinstance(exc, SystemExit) else ""
        text = "; ".join(t for t in (reason, detail) if t) or "unknown error"
        raise MeshError(f"cannot read mesh file {path}: {text}") from None


def _gather(mesh, types: tuple[str, ...], width: int) -> np.ndarray:
    """Concatenate the corner indices of all cell blocks of the given types."""
    blocks = [np.asarray(c.data)[:, :width] for c in mesh.cells if c.type in types]
    if not blocks:
        return np.zeros((0, width), dtype=np.int64)
    return np.concatenate(blocks, axis=0).astype(np.int64)


def _check_vertices(points: np.ndarray, path: Path) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or pts.shape[0] == 0:
        raise MeshError(f"{path}: expected (n, 2) or (n, 3) vertex coordinates, got shape {pts.shape}")
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if bad.size:
        raise MeshError(
            f"{path}: {bad.size} vertices have NaN or infinite coordinates (first bad vertex index {int(bad[0])})"
        )
    return pts


def _check_indices(cells: np.ndarray, num_vertices: int, path: Path, what: str) -> None:
    bad = np.flatnonzero(((cells < 0) | (cells >= num_vertices)).any(axis=1))
    if bad.size:
        raise MeshError(
            f"{path}: {bad.size} {what}s reference vertex indices outside [0, {num_vertices}) "
            f"({what} indices: {_list(bad)})"
        )


def _repeated_vertex(cells: np.ndarray) -> np.ndarray:
    s = np.sort(cells, axis=1)
    return np.flatnonzero((s[:, 1:] == s[:, :-1]).any(axis=1))


def _compact(
    vertices: np.ndarray, cells: np.ndarray, path: Path, groups: dict[str, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Drop vertices no cell references and re-index the cells (and the vertex ``groups`` masks, in place)."""
    used = np.zeros(vertices.shape[0], dtype=bool)
    used[cells.ravel()] = True
    n_unused = int(vertices.shape[0] - np.count_nonzero(used))
    if n_unused == 0:
        return vertices, cells
    logger.info("%s: removed %d unreferenced vertices", path, n_unused)
    for name in groups or {}:
        groups[name] = groups[name][used]  # type: ignore[index]
    new_index = np.cumsum(used) - 1
    return vertices[used], new_index[cells]


def _point_groups(mesh, n: int) -> dict[str, np.ndarray]:
    """Vertex groups of a meshio mesh as (n,) bool masks: point sets, and 1-D integer/bool point fields."""
    out: dict[str, np.ndarray] = {}
    for name, idx in (getattr(mesh, "point_sets", None) or {}).items():
        mask = np.zeros(n, dtype=bool)
        idx = np.asarray(idx, dtype=np.int64).ravel()
        mask[idx[(idx >= 0) & (idx < n)]] = True
        out[str(name)] = mask
    for name, arr in (mesh.point_data or {}).items():
        a = np.asarray(arr)
        if a.ndim == 1 and a.shape[0] == n and (a.dtype == bool or np.issubdtype(a.dtype, np.integer)):
            out.setdefault(str(name), a != 0)
    return out


def _orient(
    vertices: np.ndarray, elements: np.ndarray, path: Path, fix_orientation: bool, validate: bool
) -> np.ndarray:
    """Flip an all-negative mesh; reject mixed orientation and degenerate elements."""
    vol = signed_volumes(vertices, elements)
    absvol = np.abs(vol)
    degenerate = absvol <= 1e-12 * float(absvol.mean())
    negative = (vol < 0) & ~degenerate
    positive = (vol > 0) & ~degenerate
    if fix_orientation and negative.any() and not positive.any():
        elements = elements.copy()
        elements[:, [0, 1]] = elements[:, [1, 0]]
        logger.info("%s: all elements were negatively oriented; flipped them", path)
        negative, positive = positive, negative
    if not validate:
        return elements
    if degenerate.any():
        bad = np.flatnonzero(degenerate)
        raise MeshError(
            f"{path}: {bad.size} degenerate elements (zero or near-zero volume) (element indices: {_list(bad)})"
        )
    if negative.any():
        bad = np.flatnonzero(negative)
        raise MeshError(
            f"{path}: {bad.size} inverted elements (negative signed volume) among "
            f"{elements.shape[0]} (element indices: {_list(bad)})"
        )
    return elements


def _volume(
    vertices: np.ndarray,
    elements: np.ndarray,
    path: Path,
    fix_orientation: bool,
    validate: bool,
    groups: dict[str, np.ndarray] | None = None,
) -> VolumeMesh:
    _check_indices(elements, vertices.shape[0], path, "element")
    if validate:
        rep = _repeated_vertex(elements)
        if rep.size:
            raise MeshError(f"{path}: {rep.size} degenerate elements repeat a vertex (element indices: {_list(rep)})")
    groups = dict(groups or {})
    vertices, elements = _compact(vertices, elements, path, groups)
    elements = _orient(vertices, elements, path, fix_orientation, validate)
    return VolumeMesh(
        vertices=np.ascontiguousarray(vertices, dtype=np.float64),
        elements=np.ascontiguousarray(elements, dtype=np.int64),
        source=str(path),
        point_groups={k: np.flatnonzero(v).astype(np.int64) for k, v in groups.items()},
    )


def _surface(vertices: np.ndarray, faces: np.ndarray, path: Path, validate: bool) -> SurfaceMesh:
    _check_indices(faces, vertices.shape[0], path, "face")
    if validate:
        rep = _repeated_vertex(faces)
        if rep.size:
            raise MeshError(f"{path}: {rep.size} degenerate faces repeat a vertex (face indices: {_list(rep)})")
    if vertices.shape[1] == 2:
        vertices = np.column_stack([vertices, np.zeros(vertices.shape[0])])
    return SurfaceMesh(
        vertices=np.ascontiguousarray(vertices, dtype=np.float64),
        faces=np.ascontiguousarray(faces, dtype=np.int64),
        source=str(path),
    )


def read_mesh(
    path: str | os.PathLike,
    kind: str = "auto",
    *,
    fix_orientation: bool = True,
    validate: bool = True,
) -> VolumeMesh | SurfaceMesh:
    """Read and validate a mesh file.

    ``kind="auto"``: tetrahedra give a 3D :class:`VolumeMesh`; otherwise triangles with all
    z == 0 (in a format that can hold solids) give a 2D :class:`VolumeMesh`; otherwise a
    :class:`SurfaceMesh` (3D triangles, or a 2D polyline for a file of z = 0 segments).
    ``kind="volume"`` / ``"surface"`` force the choice (a tet file read as ``"surface"`` gives its
    outward boundary). ``fix_orientation`` flips a mesh whose elements are all negative;
    ``validate=False`` skips the inverted / degenerate checks (used by ``idp check`` to report
    rather than raise).
    """
    if kind not in _KINDS:
        raise MeshError(f"unknown mesh kind {kind!r}; expected one of {', '.join(_KINDS)}")
    p = Path(path)
    if not is_file(p):
        raise MeshError(f"mesh file not found: {p}{why(p)}")
    ext = p.suffix.lower()

    lines = np.zeros((0, 2), np.int64)
    groups: dict[str, np.ndarray] = {}
    if ext == ".obj":
        obj = read_obj(p)
        points, tets, tris = obj.vertices, np.zeros((0, 4), np.int64), obj.faces
    else:
        m = _read_meshio(p)
        points = m.points
        tets = _gather(m, _TET_TYPES, 4)
        tris = _gather(m, _TRI_TYPES, 3)
        lines = _gather(m, _LINE_TYPES, 2)
        # a file without a POINTS section gives 0-d points: no groups, and _check_vertices names the shape
        groups = _point_groups(m, np.shape(points)[0] if np.ndim(points) else 0)
    if tets.shape[0] == 0 and tris.shape[0] == 0 and lines.shape[0] == 0:
        raise MeshError(f"{p}: no usable cells (expected tetrahedra, triangles or 2D segments)")
    points = _check_vertices(points, p)
    planar = points.shape[1] == 2 or bool(np.all(points[:, 2] == 0.0))

    if tets.shape[0] == 0 and tris.shape[0] == 0:
        # Only segments: a 2D polyline (cage / obstacle boundary) if it lies in z = 0.
        if not planar or kind == "volume":
            raise MeshError(
                f"{p}: no usable cells (only segments, which are usable only as a 2D surface in the z = 0 plane)"
            )
        _check_indices(lines, points.shape[0], p, "segment")
        if validate:
            rep = _repeated_vertex(lines)
            if rep.size:
                raise MeshError(f"{p}: {rep.size} segments repeat a vertex (indices: {_list(rep)})")
        return SurfaceMesh(
            np.ascontiguousarray(points[:, :2], dtype=np.float64),
            np.ascontiguousarray(lines, dtype=np.int64),
            source=str(p),
        )

    if tets.shape[0] > 0:
        if points.shape[1] != 3:
            raise MeshError(f"{p}: tetrahedra need 3D vertex coordinates, got {points.shape[1]}D")
        vol = _volume(points, tets, p, fix_orientation, validate, groups)
        if kind == "surface":
            return SurfaceMesh(vol.vertices, boundary_faces(vol.elements), source=str(p))
        return vol

    if kind == "volume" or (kind == "auto" and planar and ext not in _SURFACE_ONLY_EXTS):
        if not planar:
            raise MeshError(
                f"{p}: cannot read as a volume mesh: it has no tetrahedra and its triangles "
                "are not planar (z != 0), so it is a surface"
            )
        return _volume(points[:, :2].copy(), tris, p, fix_orientation, validate, groups)
    return _surface(points, tris, p, validate)


def write_mesh(
    path: str | os.PathLike,
    mesh: VolumeMesh | SurfaceMesh,
    point_data: dict[str, np.ndarray] | None = None,
) -> None:
    """Write a volume or surface mesh with meshio (format from the extension).

    2D meshes are written with z = 0 so every format accepts them; :func:`read_mesh` reads
    them back as 2D.
    """
    import meshio

    p = Path(path)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if verts.shape[1] == 2:
        verts = np.column_stack([verts, np.zeros(verts.shape[0])])
    if isinstance(mesh, VolumeMesh):
        cells = np.asarray(mesh.elements, dtype=np.int64)
        ctype = {4: "tetra", 3: "triangle"}.get(cells.shape[1])
    elif isinstance(mesh, SurfaceMesh):
        cells = np.asarray(mesh.faces, dtype=np.int64)
        ctype = {3: "triangle", 2: "line"}.get(cells.shape[1])
    else:
        raise MeshError(f"write_mesh expects a VolumeMesh or SurfaceMesh, got {type(mesh).__name__}")
    if ctype is None:
        raise MeshError(f"cannot write cells with {cells.shape[1]} vertices each")
    out = meshio.Mesh(verts, [(ctype, cells)], point_data=dict(point_data or {}))
    try:
        out.write(str(p))
    except Exception as exc:
        raise MeshError(f"cannot write mesh file {p}: {type(exc).__name__}: {exc}") from exc
