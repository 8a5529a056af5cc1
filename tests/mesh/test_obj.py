"""The OBJ reader: index forms, vt/vn mismatches, polygons, and line-numbered errors."""

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.obj import read_obj

TEXTURED = """# textured quad + triangle, vt/vn counts differ from v
mtllib thing.mtl
o thing
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0.5 0.5 1
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
g group
usemtl red
s off
f 1/1/1 2/3/1 3/2/1
f 1//1 3//1 4//1 5//1
f 5/1 4/2 3/3
"""


def _write(tmp_path, text, name="m.obj"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reads_all_index_forms_and_fans_polygons(tmp_path):
    mesh = read_obj(_write(tmp_path, TEXTURED))
    assert mesh.vertices.shape == (5, 3)
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [4, 3, 2]]
    assert mesh.faces.dtype == np.int64
    assert mesh.extra["num_polygons"] == 3


def test_negative_relative_indices(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf -4/1 -1/2 -3/3\n"
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 3, 1]]


@pytest.mark.parametrize(
    "text, line, fragment",
    [
        ("v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n", 2, "bad number"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2\n", 5, "2 vertices"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -5\n", 4, "relative index"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 4, "index 0"),
        ("v 0 0\n", 1, "3 coordinates"),
    ],
)
def test_errors_name_file_and_line(tmp_path, text, line, fragment):
    p = _write(tmp_path, text)
    with pytest.raises(MeshError) as info:
        read_obj(p)
    msg = str(info.value)
    assert f"{p}:{line}:" in msg and fragment in msg


def test_no_faces_and_missing_file(tmp_path):
    with pytest.raises(MeshError, match="no faces"):
        read_obj(_write(tmp_path, "v 0 0 0\n"))
    with pytest.raises(MeshError, match="mesh file not found"):
        read_obj(tmp_path / "nope.obj")


def test_large_file_reads_whole(tmp_path):
    """A 20K-vertex file with v/vt/vn face indices (the vectorised reader's path) reads back whole."""
    n = 20000
    rng = np.random.default_rng(0)
    v = rng.random((n, 3))
    f = rng.integers(1, n + 1, size=(2 * n, 3))
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a}/1/1 {b}/1/1 {c}/1/1\n" for a, b, c in f)
    p = _write(tmp_path, text)
    mesh = read_obj(p)
    assert np.allclose(mesh.vertices, v) and np.array_equal(mesh.faces, f - 1)
