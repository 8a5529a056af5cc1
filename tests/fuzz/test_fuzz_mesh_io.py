"""Fuzzing ``idp.mesh.io.read_mesh``: valid VTK / VTU / MSH (meshio) and OBJ (idp's reader) files, mutated.

Property: ``read_mesh`` either raises an :class:`idp.errors.IdpError` or returns a mesh with finite coordinates
and cell indices in range (``assert_valid_mesh``), for every kind and with or without validation.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import meshio
import numpy as np
import pytest
from fuzz.common import assert_valid_mesh, fuzz, mutated_bytes
from hypothesis import example, given
from hypothesis import strategies as st

from idp.errors import IdpError
from idp.mesh.generate import box_surface, tet_box, tri_rectangle
from idp.mesh.io import read_mesh

# (file name, meshio format, meshio write options): the formats scenes name meshes in, ASCII and binary
FORMATS = {
    "vtk-ascii": ("m.vtk", "vtk", {"binary": False}),
    "vtk-binary": ("m.vtk", "vtk", {"binary": True}),
    "vtu-ascii": ("m.vtu", "vtu", {"binary": False}),
    "vtu-binary": ("m.vtu", "vtu", {"binary": True}),
    "msh22-ascii": ("m.msh", "gmsh22", {"binary": False}),
    "msh41-ascii": ("m.msh", "gmsh", {"binary": False}),
    "msh41-binary": ("m.msh", "gmsh", {"binary": True}),
}
SHAPES = ("tet", "tri2d", "surface")


@functools.cache
def _meshio_file(fmt: str, shape: str, res: int) -> bytes:
    """A valid file: a tet box, a 2D triangle rectangle or a closed box surface, in format ``fmt``."""
    name, file_format, opts = FORMATS[fmt]
    if shape == "tet":
        m = tet_box((0, 0, 0), (1, 1, 1), res)
        points, cells = m.vertices, [("tetra", m.elements)]
    elif shape == "tri2d":
        m2 = tri_rectangle((0, 0), (1, 1), res)
        points, cells = np.c_[m2.vertices, np.zeros(m2.num_vertices)], [("triangle", m2.elements)]
    else:
        s = box_surface((-1, -1, -1), (1, 1, 1), res)
        points, cells = s.vertices, [("triangle", s.faces)]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / name
        meshio.write(str(path), meshio.Mesh(points, cells), file_format=file_format, **opts)
        return path.read_bytes()


@functools.cache
def _obj_file(res: int, polygons: bool) -> bytes:
    """A valid OBJ: a box surface with vt/vn lines, groups and comments (quads when ``polygons``)."""
    s = box_surface((-1, -1, -1), (1, 1, 1), res)
    lines = ["# box", "mtllib box.mtl", "o box"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in s.vertices.tolist()]
    lines += ["vt 0 0", "vt 1 0", "vt 0 1", "vn 0 0 1", "g side", "usemtl paper", "s 1"]
    faces = s.faces.tolist()
    if polygons and len(faces) % 2 == 0:
        # a quad is two triangles sharing an edge: idp fan-triangulates it back
        for a, b in zip(faces[::2], faces[1::2], strict=True):
            lines.append(f"f {a[0] + 1}/1/1 {a[1] + 1}/2/1 {a[2] + 1}/3/1")
            lines.append(f"f {b[0] + 1}//1 {b[1] + 1}//1 {b[2] + 1}//1")
    else:
        n = s.num_vertices
        lines += [f"f {a - n} {b - n} {c - n}" for a, b, c in faces]  # relative indices
    return ("\n".join(lines) + "\n").encode()


def _read(data: bytes, name: str, kind: str, validate: bool) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / name
        path.write_bytes(data)
        try:
            mesh = read_mesh(path, kind=kind, validate=validate)
        except IdpError as exc:
            assert str(exc), "an IdpError without a message"
            return
        assert_valid_mesh(mesh)


@fuzz(300)
@given(
    fmt=st.sampled_from(sorted(FORMATS)),
    shape=st.sampled_from(SHAPES),
    res=st.integers(1, 2),
    kind=st.sampled_from(["auto", "volume", "surface"]),
    validate=st.booleans(),
    data=st.data(),
)
def test_meshio_formats_mutated(fmt, shape, res, kind, validate, data):
    name = FORMATS[fmt][0]
    mutated = data.draw(mutated_bytes(_meshio_file(fmt, shape, res)), label="file")
    _read(mutated, name, kind, validate)


@fuzz(300)
@given(
    res=st.integers(1, 2),
    polygons=st.booleans(),
    kind=st.sampled_from(["auto", "volume", "surface"]),
    validate=st.booleans(),
    data=st.data(),
)
@example(res=1, polygons=False, kind="auto", validate=True, data=None)  # the unmutated file reads
def test_obj_mutated(res, polygons, kind, validate, data):
    base = _obj_file(res, polygons)
    if data is None:
        with tempfile.TemporaryDirectory() as d:
            (Path(d) / "m.obj").write_bytes(base)
            assert_valid_mesh(read_mesh(Path(d) / "m.obj"))
        return
    _read(data.draw(mutated_bytes(base), label="file"), "m.obj", kind, validate)


@fuzz(60)
@given(
    ext=st.sampled_from([".vtk", ".vtu", ".msh", ".obj", ".stl", ".ply", ".off", ".mesh", ".xyz", ""]),
    data=st.binary(max_size=512),
)
def test_random_bytes(ext, data):
    _read(data, "m" + ext, "auto", True)


@pytest.mark.parametrize(
    "text",
    [
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n",  # face index beyond int64
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -99999999999999999999999\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9223372036854775808\n",
    ],
)
def test_obj_index_beyond_int64(tmp_path, text):
    """Regression: an index too large for int64 raised OverflowError from numpy instead of a MeshError."""
    p = tmp_path / "m.obj"
    p.write_text(text)
    with pytest.raises(IdpError, match=r"out of range|refers before"):
        read_mesh(p)


@pytest.mark.parametrize("name", ["x" * 5000 + ".obj", "x" * 5000 + "/m.vtk", "a\x00b.obj"])
def test_paths_the_system_cannot_look_up(name):
    """Regression: a name longer than the file system allows made Path.is_file() raise OSError (ENAMETOOLONG) in
    every reader; now it is a MeshError naming the path and the system's reason."""
    from idp.mesh.checks import check_mesh
    from idp.mesh.sequence import open_sequence
    from idp.mesh.uv_obj import read_uv_obj

    for reader in (read_mesh, read_uv_obj, open_sequence):
        with pytest.raises(IdpError, match="not found"):
            reader(name)
    assert check_mesh(name).kind == "unreadable"


@fuzz(300)
@given(
    data=st.lists(
        st.one_of(
            st.sampled_from([b"\n", b"\r", b"\r\n", b"\x0b", b"\x0c", b"\x1c", b"\xc2\x85", b"\xe2\x80\xa8", b"\xff"]),
            st.sampled_from([b"v 1 2 3", b"f 1 2 3", b"vt 0 1", b"# c", b"\xe2\x82\xac", b"\xe2", b"\x82\xac"]),
            st.binary(max_size=5),
        ),
        max_size=40,
    ).map(b"".join),
    chunk=st.integers(1, 9),
    text=st.booleans(),
)
def test_read_lines_is_splitlines(data, chunk, text):
    """The OBJ readers' streaming line splitter gives exactly the lines of str/bytes.splitlines() of the whole file,
    whatever the chunk boundaries (a \\r\\n or a UTF-8 sequence cut in two)."""
    from idp.mesh import obj

    saved = obj._CHUNK
    obj._CHUNK = chunk
    try:
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "m.obj"
            p.write_bytes(data)
            whole = data.decode("utf-8", errors="replace") if text else data
            assert list(obj.read_lines(p, text=text)) == list(enumerate(whole.splitlines(), start=1))
    finally:
        obj._CHUNK = saved


def test_vtk_without_points(tmp_path):
    """Regression: a legacy VTK file with cells but no POINTS section gave meshio 0-d points, and read_mesh an
    IndexError (found at IDP_FUZZ_SCALE=10)."""
    p = tmp_path / "m.vtk"
    p.write_text(
        "# vtk DataFile Version 5.1\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nCELLS 2 4\nOFFSETS vtktypeint64\n0\n4\n"
        "CONNECTIVITY vtktypeint64\n0\n1\n2\n3\nCELL_TYPES 1\n10\n"
    )
    for validate in (True, False):
        with pytest.raises(IdpError, match="vertex coordinates"):
            read_mesh(p, validate=validate)
