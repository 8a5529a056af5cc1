"""OBJ meshes with a UV layout, for ``idp uv`` (paper §7.4: lowering the worst-case distortion of a UV map).

The UV map is a piecewise-linear map from the 3D triangles to the plane: each face names three ``v`` (3D
positions) and three ``vt`` (UV coordinates); seams give one ``v`` several ``vt``. This module

* reads such a file (:func:`read_uv_obj`, triangles only, every corner with a ``vt``), with errors naming the
  file and line;
* gives the rest metric of each triangle (:func:`uv_rest_frames`: its 3D edges in a basis of its own plane);
* checks the layout's orientation (:func:`orient_uv_mesh`: a mirrored layout is turned, a mixed one refused) and
  finds overlapping UV triangles (:func:`uv_overlaps`, global non-injectivity);
* writes the result back (:func:`write_uv_obj`) as a byte-exact copy of the source in which only the numbers on
  the ``vt`` lines change, so materials, normals, groups and the author's formatting survive.

Files are handled as bytes: lines are split on ``\\n``, ``\\r\\n`` and ``\\r`` alike in the reader and the
writer, so the ``k``-th ``vt`` line the reader sees is the one the writer rewrites.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from idp.errors import MeshError, OutputError
from idp.fs import is_dir, is_file, make_output_dir, why
from idp.mesh.obj import read_lines

_LIST = 10  # how many offending triangles an error message names
_DEGENERATE = 1e-12  # |cross(e1, e2)| below this times the longest squared edge: a triangle without area
_CCW_ERR = 3.4e-16  # Shewchuk's ccwerrboundA, (3 + 16ε)ε with ε = 2⁻⁵³, rounded up
_CHUNK = 262_144  # candidate pairs tested at once by uv_overlaps
_MAX_INDEX = int(np.iinfo(np.int64).max)  # an index beyond int64 is never in range (and numpy cannot hold it)


@dataclass
class UVMesh:
    """A triangle mesh with a UV layout, as read from an OBJ file.

    ``positions`` (n, 3): the ``v`` lines; ``uv`` (nt, 2): the first two numbers of the ``vt`` lines;
    ``faces_xyz`` / ``faces_uv`` (m, 3): 0-based ``v`` / ``vt`` indices per corner; ``face_lines`` (m,): the
    1-based line number of each face in ``source`` (for error messages).
    """

    positions: np.ndarray
    uv: np.ndarray
    faces_xyz: np.ndarray
    faces_uv: np.ndarray
    source: str
    face_lines: np.ndarray


# ------------------------------------------------------------------------------------------------------- reading


def _fail(path: Path | str, lineno: int, msg: str) -> MeshError:
    return MeshError(f"{path}:{lineno}: {msg}")


def _no_vt(path: Path) -> MeshError:
    return MeshError(f"{path}: has no texture coordinates (vt lines); idp uv needs a UV layout")


def _text(line: bytes) -> str:
    return line.decode("utf-8", errors="replace").strip()


def _index(tok: bytes, count: int, what: str, path: Path, lineno: int, corner: bytes) -> int:
    """A 0-based index from an OBJ index token: positive from the first element, negative relative to the
    ``count`` elements read so far (OBJ's relative indices); 0 is invalid."""
    try:
        k = int(tok)
    except ValueError:
        raise _fail(path, lineno, f"bad {what} index {_text(tok)!r} in face corner {_text(corner)!r}") from None
    if k > _MAX_INDEX:
        raise _fail(path, lineno, f"{what} index {k} out of range")
    if k > 0:
        return k - 1
    if k < 0:
        if count + k < 0:
            raise _fail(
                path,
                lineno,
                f"relative {what} index {k} refers before the first {what} ({count} {what} lines read so far)",
            )
        return count + k
    raise _fail(path, lineno, f"{what} index 0 is invalid (OBJ indices start at 1)")


def _numbers(tokens: list[bytes], lines: list[int], per: int, what: str, path: Path) -> np.ndarray:
    """Parse ``per`` numbers per line at once; on a bad or non-finite number name its line."""
    try:
        arr = np.array(tokens, dtype=np.float64).reshape(-1, per)
    except ValueError:
        for k, tok in enumerate(tokens):
            try:
                float(tok)
            except ValueError:
                raise _fail(path, lines[k // per], f"bad number {_text(tok)!r} in {what} line") from None
        raise  # pragma: no cover - numpy and float() accept the same numbers
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad.size:
        i = int(bad[0])
        more = f" ({bad.size} such {what} lines)" if bad.size > 1 else ""
        raise _fail(path, lines[i], f"non-finite number in {what} line: {arr[i].tolist()}{more}")
    return arr


def read_uv_obj(path: str | os.PathLike) -> UVMesh:
    """Read the triangles, 3D positions and UV layout of an OBJ file.

    Every face must be a triangle whose corners all name a ``vt`` (``f v/vt`` or ``f v/vt/vn``); ``vt u v w``
    is accepted (w is ignored), negative indices count back from the last element read. Errors (``MeshError``)
    name the file and line.
    """
    p = Path(path)
    if not is_file(p):
        raise MeshError(f"mesh file not found: {p}{why(p)}")
    v_tok: list[bytes] = []
    v_line: list[int] = []
    t_tok: list[bytes] = []
    t_line: list[int] = []
    f_v: list[int] = []
    f_t: list[int] = []
    f_line: list[int] = []
    stream = read_lines(p, text=False)  # O(MAX_LINE) of the file at a time, see idp.mesh.obj.MAX_LINE
    for lineno, line in stream:
        parts = line.split()
        if not parts:
            continue
        tag = parts[0]
        if tag == b"v":
            if len(parts) < 4:
                raise _fail(p, lineno, f"vertex needs 3 coordinates: {_text(line)!r}")
            v_tok += parts[1:4]
            v_line.append(lineno)
        elif tag == b"vt":
            if len(parts) < 3:
                raise _fail(p, lineno, f"texture coordinate needs at least 2 numbers (u v): {_text(line)!r}")
            t_tok += parts[1:3]
            t_line.append(lineno)
        elif tag == b"f":
            corners = parts[1:]
            if len(corners) > 3:
                raise _fail(
                    p,
                    lineno,
                    f"face with {len(corners)} corners: idp uv reads triangles only, triangulate the mesh first",
                )
            if len(corners) < 3:
                raise _fail(p, lineno, f"face with {len(corners)} corners (a triangle needs 3)")
            nv, nt = len(v_line), len(t_line)
            for corner in corners:
                fields = corner.split(b"/")
                if len(fields) < 2 or not fields[1]:
                    if not t_line and not any(rest.split()[:1] == [b"vt"] for _, rest in stream):
                        raise _no_vt(p)  # the file has no vt at all: say that, not which corner lacks one
                    raise _fail(
                        p,
                        lineno,
                        f"face corner {_text(corner)!r} has no texture coordinate index: idp uv needs every "
                        "corner as v/vt or v/vt/vn",
                    )
                f_v.append(_index(fields[0], nv, "v", p, lineno, corner))
                f_t.append(_index(fields[1], nt, "vt", p, lineno, corner))
            f_line.append(lineno)

    if not t_line:
        raise _no_vt(p)
    if not f_line:
        raise MeshError(f"{p}: no faces found in OBJ file")
    positions = _numbers(v_tok, v_line, 3, "v", p)
    uv = _numbers(t_tok, t_line, 2, "vt", p)
    faces_xyz = np.asarray(f_v, dtype=np.int64).reshape(-1, 3)
    faces_uv = np.asarray(f_t, dtype=np.int64).reshape(-1, 3)
    lines = np.asarray(f_line, dtype=np.int64)
    for faces, count, what in ((faces_xyz, positions.shape[0], "v"), (faces_uv, uv.shape[0], "vt")):
        bad = np.flatnonzero((faces >= count).any(axis=1))
        if bad.size:
            i = int(bad[0])
            raise _fail(
                p, int(lines[i]), f"{what} index {int(faces[i].max()) + 1} out of range (file has {count} {what} lines)"
            )
    return UVMesh(positions=positions, uv=uv, faces_xyz=faces_xyz, faces_uv=faces_uv, source=str(p), face_lines=lines)


# ---------------------------------------------------------------------------------------------------- geometry


def _where(ids: np.ndarray, face_lines: np.ndarray | None) -> str:
    """``"3 (line 17), 8 (line 22), ..."``: the first triangle ids, with their lines where known."""
    shown = [int(i) for i in ids[:_LIST]]
    items = [f"{i} (line {int(face_lines[i])})" if face_lines is not None else str(i) for i in shown]
    return ", ".join(items) + (", ..." if ids.size > _LIST else "")


def _prefix(ids: np.ndarray, face_lines: np.ndarray | None, source: str) -> str:
    """``"file:line: "`` of the first offending triangle, ``"file: "`` or nothing, as much as is known."""
    if source and face_lines is not None and ids.size:
        return f"{source}:{int(face_lines[int(ids[0])])}: "
    return f"{source}: " if source else ""


def uv_rest_frames(
    positions: np.ndarray, faces_xyz: np.ndarray, *, face_lines: np.ndarray | None = None, source: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """The rest matrix ``Dm`` (m, 2, 2) and the 3D area (m,) of each triangle.

    The columns of ``Dm`` are the edges x1 − x0 and x2 − x0 in an orthonormal basis of the triangle's plane (first
    axis along x1 − x0, second n × first), so ``det Dm = 2·area > 0`` and ``F = Ds Dm⁻¹`` is the UV map's
    Jacobian. Triangles without area (or with non-finite corners) have no rest metric: a ``MeshError`` names how
    many and the first ids (with their lines when ``face_lines`` is given; ``source`` names the file).
    """
    x = np.asarray(positions, dtype=np.float64)[np.asarray(faces_xyz, dtype=np.int64)]
    e1 = x[:, 1] - x[:, 0]
    e2 = x[:, 2] - x[:, 0]
    n = np.cross(e1, e2)
    twice = np.linalg.norm(n, axis=1)
    len1 = np.linalg.norm(e1, axis=1)
    longest = np.maximum(np.maximum(len1, np.linalg.norm(e2, axis=1)), np.linalg.norm(x[:, 2] - x[:, 1], axis=1))
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.isfinite(twice) & np.isfinite(longest) & (twice > _DEGENERATE * longest**2)
    bad = np.flatnonzero(~ok)
    if bad.size:
        raise MeshError(
            f"{_prefix(bad, face_lines, source)}{bad.size} triangle(s) of {len(x)} have no 3D area (degenerate or "
            f"non-finite), the rest metric is undefined there: triangles {_where(bad, face_lines)}"
        )
    b1 = e1 / len1[:, None]
    b2 = np.cross(n / twice[:, None], b1)
    dm = np.zeros((len(x), 2, 2))
    dm[:, 0, 0] = len1
    dm[:, 0, 1] = np.einsum("ij,ij->i", e2, b1)
    dm[:, 1, 1] = np.einsum("ij,ij->i", e2, b2)
    return dm, 0.5 * twice


def uv_signed_areas(uv: np.ndarray, faces_uv: np.ndarray) -> np.ndarray:
    """Signed area (m,) of each UV triangle: positive when its corners run counter-clockwise."""
    t = np.asarray(uv, dtype=np.float64)[np.asarray(faces_uv, dtype=np.int64)]
    a = t[:, 1] - t[:, 0]
    b = t[:, 2] - t[:, 0]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def _uv_degenerate(uv: np.ndarray, faces_uv: np.ndarray, areas: np.ndarray) -> np.ndarray:
    t = uv[faces_uv]
    sq = np.stack([((t[:, (k + 1) % 3] - t[:, k]) ** 2).sum(axis=1) for k in range(3)], axis=1).max(axis=1)
    return ~(np.abs(2.0 * areas) > _DEGENERATE * sq)


def orient_uv_mesh(mesh: UVMesh) -> tuple[UVMesh, bool]:
    """The mesh with every UV triangle counter-clockwise, and whether the layout had to be mirrored.

    A layout whose triangles all run clockwise (a mirrored layout) is returned with corners 1 and 2 swapped in
    both ``faces_xyz`` and ``faces_uv`` (the same map, positively oriented). A layout with both orientations (the
    minority counts as flipped) or with UV triangles without area is not a locally injective map: ``MeshError``
    with the count and the first ids and lines. The ``vt`` values are not changed.
    """
    areas = uv_signed_areas(mesh.uv, mesh.faces_uv)
    m = areas.size
    lines = mesh.face_lines
    degenerate = np.flatnonzero(_uv_degenerate(mesh.uv, mesh.faces_uv, areas))
    if degenerate.size:
        raise MeshError(
            f"{_prefix(degenerate, lines, mesh.source)}{degenerate.size} UV triangle(s) of {m} have no area in the "
            f"UV layout: triangles {_where(degenerate, lines)}; idp uv needs a locally injective UV map to start from"
        )
    negative = areas < 0
    count = int(negative.sum())
    if count == m:
        faces_xyz = mesh.faces_xyz[:, [0, 2, 1]]
        faces_uv = mesh.faces_uv[:, [0, 2, 1]]
        return replace(mesh, faces_xyz=faces_xyz, faces_uv=faces_uv), True
    if count:
        flipped = np.flatnonzero(negative if 2 * count <= m else ~negative)
        raise MeshError(
            f"{_prefix(flipped, lines, mesh.source)}the UV layout has {flipped.size} flipped triangle(s) of {m} "
            f"(their orientation is opposite to the other {m - flipped.size}): triangles {_where(flipped, lines)}; "
            "idp uv needs a locally injective UV map to start from"
        )
    return mesh, False


# ----------------------------------------------------------------------------------------------------- overlaps


def _certainly_separated(xs: np.ndarray, ys: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Pairs (i, j) of counter-clockwise triangles (corner coordinates ``xs``, ``ys``, each (3, m)) whose
    interiors are disjoint for certain: some edge of one triangle has every corner of the other on its outer
    side, each either a copy of the edge's end points (the orientation is then exactly 0) or strictly outside
    beyond the float error bound of the orientation test (Shewchuk's orient2d bound)."""
    out = np.zeros(i.size, dtype=bool)
    for own, other in ((i, j), (j, i)):
        todo = np.flatnonzero(~out)
        ox, oy = xs[:, own[todo]], ys[:, own[todo]]
        px, py = xs[:, other[todo]], ys[:, other[todo]]
        found = np.zeros(todo.size, dtype=bool)
        for e in range(3):
            ax, ay, bx, by = ox[e], oy[e], ox[(e + 1) % 3], oy[(e + 1) % 3]
            ex, ey = bx - ax, by - ay
            every = np.ones(todo.size, dtype=bool)
            for c in range(3):
                left = ex * (py[c] - ay)
                right = ey * (px[c] - ax)
                outside = (left - right) < -_CCW_ERR * (np.abs(left) + np.abs(right))
                outside |= ((px[c] == ax) & (py[c] == ay)) | ((px[c] == bx) & (py[c] == by))
                every &= outside
            found |= every
        out[todo[found]] = True
    return out


def uv_overlaps(uv: np.ndarray, faces_uv: np.ndarray, max_pairs: int | None = None) -> np.ndarray:
    """Pairs (k, 2), i < j, of UV triangles whose interiors overlap: the layout is not injective there (two
    charts, or two parts of one chart, on top of each other). Triangles that only touch (shared or coinciding
    edges and corners) are not reported, nor triangles without area.

    Candidates come from an STR tree of the triangles' bounding boxes; pairs that a vectorised separating-edge
    test proves disjoint (beyond floating-point doubt) are dropped, and the rest decided exactly by GEOS
    (``relate_pattern(a, b, "2********")``: the interiors meet in an area). ``max_pairs``: stop once that many
    are found (the result is then a subset).
    """
    import shapely

    pts = np.asarray(uv, dtype=np.float64)
    faces = np.asarray(faces_uv, dtype=np.int64).reshape(-1, 3)
    empty = np.zeros((0, 2), dtype=np.int64)
    areas = uv_signed_areas(pts, faces)
    live = np.flatnonzero(areas != 0)
    if live.size < 2:
        return empty
    ccw = faces[live]
    ccw[areas[live] < 0] = ccw[areas[live] < 0][:, [0, 2, 1]]  # the same triangles, all counter-clockwise
    tri = pts[ccw]
    xs, ys = np.ascontiguousarray(tri[:, :, 0].T), np.ascontiguousarray(tri[:, :, 1].T)
    polys = shapely.polygons(np.concatenate([tri, tri[:, :1]], axis=1))
    i, j = shapely.STRtree(polys).query(polys)
    keep = i < j
    i, j = i[keep], j[keep]
    found: list[np.ndarray] = []
    total = 0
    for start in range(0, i.size, _CHUNK):
        ci, cj = i[start : start + _CHUNK], j[start : start + _CHUNK]
        doubt = ~_certainly_separated(xs, ys, ci, cj)
        ci, cj = ci[doubt], cj[doubt]
        if ci.size:
            hit = shapely.relate_pattern(polys[ci], polys[cj], "2********")
            pairs = np.stack([live[ci[hit]], live[cj[hit]]], axis=1)
            found.append(pairs)
            total += len(pairs)
        if max_pairs is not None and total >= max_pairs:
            break
    if not found:
        return empty
    pairs = np.concatenate(found).astype(np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return pairs[:max_pairs] if max_pairs is not None else pairs


# ------------------------------------------------------------------------------------------------------- writing

_VT = re.compile(rb"(\s*vt\s+)(\S+)(\s+)(\S+)(.*)", re.DOTALL)


def _same_file(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def write_uv_obj(source: str | os.PathLike, out: str | os.PathLike, uv: np.ndarray, *, overwrite: bool = False) -> Path:
    """Write a copy of ``source`` whose ``vt`` lines carry ``uv`` (nt, 2), in order; return the path written.

    Only the two numbers of each ``vt`` line change (a third ``w``, comments and the spacing stay); every other
    byte is the source's, line endings included. Numbers are written with ``repr`` (the shortest text that reads
    back as the same float). The file is written to a temporary file beside ``out`` and moved into place, so a
    failure never leaves half a file. Writing over ``source`` itself needs ``overwrite=True``.
    """
    src, dst = Path(source), Path(out)
    values = np.asarray(uv, dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != 2:
        raise MeshError(f"UV coordinates for {dst} must have shape (nt, 2), got {values.shape}")
    if not np.isfinite(values).all():
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        raise MeshError(f"UV coordinates for {dst} are not finite at {bad.size} vt(s), first {bad[:_LIST].tolist()}")
    if not is_file(src):
        raise MeshError(f"mesh file not found: {src}{why(src)}")
    if is_dir(dst):
        raise OutputError(f"{dst}: is a folder, not an OBJ file to write")
    if not overwrite and _same_file(src, dst):
        raise MeshError(f"{dst}: is the source OBJ itself; refusing to overwrite it (pass overwrite=True)")
    try:
        data = src.read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot read mesh file {src}: {exc}") from exc

    lines = data.splitlines(keepends=True)
    rows = values.tolist()
    k = 0
    for n, line in enumerate(lines):
        parts = line.split(None, 1)
        if not parts or parts[0] != b"vt":
            continue
        body = line.rstrip(b"\r\n")
        match = _VT.fullmatch(body)
        if match is None:
            raise _fail(src, n + 1, f"texture coordinate needs at least 2 numbers (u v): {_text(line)!r}")
        if k < len(rows):
            u, v = rows[k]
            head, _, gap, _, tail = match.groups()
            lines[n] = b"".join((head, repr(u).encode(), gap, repr(v).encode(), tail, line[len(body) :]))
        k += 1
    if k != len(rows):
        raise MeshError(f"{src}: has {k} vt lines but {len(rows)} UV coordinates were given")

    make_output_dir(dst.parent)
    mode = dst.stat().st_mode & 0o777 if dst.exists() else 0o644
    fd, tmp = tempfile.mkstemp(prefix=f".{dst.name}.", suffix=".tmp", dir=dst.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.writelines(lines)
        os.chmod(tmp, mode)
        os.replace(tmp, dst)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return dst


# ------------------------------------------------------------------------------------------------- test meshes


def cut_cylinder_obj_text(
    segments: int = 8,
    rings: int = 3,
    *,
    radius: float = 1.0,
    height: float = 2.0,
    uv_scale: tuple[float, float] = (1.0, 1.0),
    newline: str = "\n",
    w: bool = False,
) -> str:
    """OBJ text of an open cylinder surface cut along one seam and unrolled: ``segments`` × ``rings`` quads,
    each split into two counter-clockwise triangles (in UV). The seam's vertices carry two ``vt`` each. With
    ``uv_scale = (1, 1)`` each UV triangle is congruent to its flat 3D triangle (an isometric layout, symmetric
    Dirichlet = 4). The text has comments, ``mtllib``/``o``/``g``/``usemtl``/``s`` lines and normals (``f v/vt/vn``),
    as exported models do, to test that the writer keeps them; ``w`` adds a third ``vt`` number."""
    chord = 2.0 * radius * math.sin(math.pi / segments)
    lines = ["# cut cylinder made by idp (test mesh)", "mtllib cylinder.mtl", "o cylinder", ""]
    for r in range(rings + 1):
        z = height * r / rings
        for s in range(segments):
            t = 2.0 * math.pi * s / segments
            lines.append(f"v {radius * math.cos(t):.17g} {radius * math.sin(t):.17g} {z:.17g}")
    lines.append("")
    for r in range(rings + 1):
        for s in range(segments + 1):
            u, v = uv_scale[0] * chord * s, uv_scale[1] * height * r / rings
            lines.append(f"vt {u:.17g} {v:.17g}" + (" 0" if w else ""))
    for s in range(segments):
        t = 2.0 * math.pi * (s + 0.5) / segments
        lines.append(f"vn {math.cos(t):.17g} {math.sin(t):.17g} 0")
    lines += ["g side", "usemtl paper", "s 1"]
    for r in range(rings):
        for s in range(segments):
            v00, v01 = r * segments + s + 1, r * segments + (s + 1) % segments + 1
            v10, v11 = v00 + segments, v01 + segments
            t00 = r * (segments + 1) + s + 1
            t01, t10, t11 = t00 + 1, t00 + segments + 1, t00 + segments + 2
            n = s + 1
            lines.append(f"f {v00}/{t00}/{n} {v01}/{t01}/{n} {v11}/{t11}/{n}")
            lines.append(f"f {v00}/{t00}/{n} {v11}/{t11}/{n} {v10}/{t10}/{n}")
    lines.append("# end")
    return newline.join(lines) + newline


__all__ = [
    "UVMesh",
    "cut_cylinder_obj_text",
    "orient_uv_mesh",
    "read_uv_obj",
    "uv_overlaps",
    "uv_rest_frames",
    "uv_signed_areas",
    "write_uv_obj",
]
