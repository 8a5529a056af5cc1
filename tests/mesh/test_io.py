"""read_mesh / write_mesh: round trips, kind detection, and every validation error."""

import logging

import meshio
import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.generate import box_surface, tet_box, tri_rectangle
from idp.mesh.io import read_mesh, write_mesh
from idp.mesh.quality import signed_volumes
from idp.mesh.types import SurfaceMesh, VolumeMesh

UNIT_TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
TWO_TETS = np.array([[0, 1, 2, 3], [1, 4, 2, 3]])  # both positive


def _write_raw(path, points, cells):
    meshio.Mesh(points, cells).write(str(path))
    return path


@pytest.mark.parametrize("ext", [".vtk", ".msh", ".vtu"])
def test_volume_round_trip(tmp_path, ext):
    mesh = tet_box(resolution=2)
    write_mesh(tmp_path / f"box{ext}", mesh)
    back = read_mesh(tmp_path / f"box{ext}")
    assert isinstance(back, VolumeMesh) and back.dim == 3
    assert np.allclose(back.vertices, mesh.vertices)
    assert np.array_equal(back.elements, mesh.elements)
    assert back.source == str(tmp_path / f"box{ext}")


@pytest.mark.parametrize("ext", [".vtk", ".msh"])
def test_2d_round_trip(tmp_path, ext):
    mesh = tri_rectangle(resolution=(3, 2))
    write_mesh(tmp_path / f"rect{ext}", mesh)
    back = read_mesh(tmp_path / f"rect{ext}")
    assert isinstance(back, VolumeMesh) and back.dim == 2
    assert np.allclose(back.vertices, mesh.vertices)
    assert np.array_equal(back.elements, mesh.elements)


@pytest.mark.parametrize("ext", [".stl", ".obj", ".ply", ".vtk"])
def test_surface_round_trip(tmp_path, ext):
    s = box_surface(resolution=2)
    write_mesh(tmp_path / f"s{ext}", s)
    back = read_mesh(tmp_path / f"s{ext}")
    assert isinstance(back, SurfaceMesh) and back.vertices.shape[1] == 3
    assert back.faces.shape == s.faces.shape
    assert np.allclose(back.vertices[back.faces], s.vertices[s.faces], atol=1e-6)


def test_planar_surface_kinds(tmp_path):
    flat = tri_rectangle()
    p = write_path = tmp_path / "flat.stl"
    write_mesh(write_path, SurfaceMesh(flat.vertices, flat.elements))
    assert isinstance(read_mesh(p), SurfaceMesh)  # .stl is always a surface
    assert read_mesh(p, kind="volume").dim == 2
    q = tmp_path / "flat.vtk"
    write_mesh(q, flat)
    assert isinstance(read_mesh(q, kind="surface"), SurfaceMesh)


def test_volume_kind_on_curved_surface_is_error(tmp_path):
    p = tmp_path / "box.vtk"
    write_mesh(p, box_surface())
    with pytest.raises(MeshError, match="not planar"):
        read_mesh(p, kind="volume")
    assert isinstance(read_mesh(p), SurfaceMesh)


def test_tet_file_as_surface_gives_boundary(tmp_path):
    p = tmp_path / "box.vtu"
    write_mesh(p, tet_box(resolution=2))
    s = read_mesh(p, kind="surface")
    assert isinstance(s, SurfaceMesh) and s.faces.shape == (6 * 8, 3)


def test_missing_file_and_bad_kind(tmp_path):
    with pytest.raises(MeshError, match=r"mesh file not found: .*nothing\.msh"):
        read_mesh(tmp_path / "nothing.msh")
    with pytest.raises(MeshError, match="unknown mesh kind"):
        read_mesh(tmp_path / "nothing.msh", kind="solid")


def test_unreadable_file(tmp_path):
    p = tmp_path / "junk.xyz"
    p.write_text("hello")
    with pytest.raises(MeshError, match=r"cannot read mesh file .*junk\.xyz"):
        read_mesh(p)
    q = tmp_path / "junk.vtk"
    q.write_text("not a vtk file at all\n")
    with pytest.raises(MeshError, match=r"junk\.vtk"):
        read_mesh(q)


def test_no_usable_cells(tmp_path):
    p = _write_raw(tmp_path / "lines.vtk", UNIT_TET, [("line", np.array([[0, 1]]))])
    with pytest.raises(MeshError, match="no usable cells"):
        read_mesh(p)


def test_nan_vertex_is_named(tmp_path):
    pts = UNIT_TET.copy()
    pts[3, 1] = np.nan
    pts[4, 0] = np.inf
    p = _write_raw(tmp_path / "nan.vtu", pts, [("tetra", TWO_TETS)])
    with pytest.raises(MeshError, match=r"2 vertices .*first bad vertex index 3"):
        read_mesh(p)


def test_index_out_of_range(tmp_path):
    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n")
    with pytest.raises(MeshError, match=r"bad\.obj:5: .*out of range"):
        read_mesh(p)
    # meshio itself accepts out-of-range indices in .vtu: read_mesh must catch them.
    q = _write_raw(tmp_path / "bad.vtu", UNIT_TET, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 7]]))])
    with pytest.raises(MeshError, match=r"outside \[0, 5\) \(element indices: 1\)"):
        read_mesh(q)


def test_repeated_vertex_is_degenerate(tmp_path):
    p = _write_raw(tmp_path / "rep.vtu", UNIT_TET, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 1, 4]]))])
    with pytest.raises(MeshError, match=r"degenerate.*repeat a vertex.*indices: 1\)"):
        read_mesh(p)


def test_flat_element_is_degenerate(tmp_path):
    pts = np.vstack([UNIT_TET, [[0.3, 0.3, 0.0]]])
    p = _write_raw(tmp_path / "flat.vtu", pts, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 5]]))])
    with pytest.raises(MeshError, match=r"1 degenerate elements .*indices: 1\)"):
        read_mesh(p)
    raw = read_mesh(p, validate=False)
    assert raw.num_elements == 2


def test_all_negative_file_is_flipped(tmp_path):
    p = _write_raw(tmp_path / "neg.vtu", UNIT_TET, [("tetra", TWO_TETS[:, [1, 0, 2, 3]])])
    mesh = read_mesh(p)
    assert np.all(signed_volumes(mesh.vertices, mesh.elements) > 0)
    raw = read_mesh(p, fix_orientation=False, validate=False)
    assert np.all(signed_volumes(raw.vertices, raw.elements) < 0)
    with pytest.raises(MeshError, match="inverted"):
        read_mesh(p, fix_orientation=False)


def test_mixed_orientation_names_indices(tmp_path):
    box = tet_box(resolution=3)
    elems = box.elements.copy()
    bad = [4, 17, 50]
    elems[bad] = elems[bad][:, [1, 0, 2, 3]]
    p = _write_raw(tmp_path / "mixed.vtu", box.vertices, [("tetra", elems)])
    with pytest.raises(MeshError, match=r"3 inverted elements .*indices: 4, 17, 50\)"):
        read_mesh(p)
    assert read_mesh(p, validate=False).num_elements == elems.shape[0]


def test_many_inverted_are_truncated(tmp_path):
    box = tet_box(resolution=3)
    elems = box.elements.copy()
    elems[:20] = elems[:20][:, [1, 0, 2, 3]]
    p = _write_raw(tmp_path / "mixed.vtu", box.vertices, [("tetra", elems)])
    with pytest.raises(MeshError, match=r"20 inverted .*indices: 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, \.\.\.\)"):
        read_mesh(p)


def test_unreferenced_vertices_are_removed(tmp_path, caplog):
    pts = np.vstack([[[9.0, 9, 9]], UNIT_TET])
    p = _write_raw(tmp_path / "extra.vtu", pts, [("tetra", TWO_TETS + 1)])
    with caplog.at_level(logging.INFO, logger="idp"):
        mesh = read_mesh(p)
    assert mesh.num_vertices == 5
    assert np.allclose(mesh.vertices, UNIT_TET)
    assert np.array_equal(mesh.elements, TWO_TETS)
    assert "1 unreferenced" in caplog.text


def test_2d_negative_triangles_flipped(tmp_path):
    rect = tri_rectangle(resolution=(2, 2))
    p = tmp_path / "cw.vtk"
    write_mesh(p, VolumeMesh(rect.vertices, rect.elements[:, [0, 2, 1]]))
    mesh = read_mesh(p)
    assert mesh.dim == 2 and np.all(signed_volumes(mesh.vertices, mesh.elements) > 0)


def test_2d_polyline_round_trip(tmp_path):
    from idp.mesh.generate import polygon_circle

    c = polygon_circle(1.0, (0.5, 0.0), segments=12)
    write_mesh(tmp_path / "cage.vtk", c)
    back = read_mesh(tmp_path / "cage.vtk")
    assert isinstance(back, SurfaceMesh) and back.vertices.shape == (12, 2)
    assert np.allclose(back.vertices, c.vertices) and np.array_equal(back.faces, c.faces)
    with pytest.raises(MeshError, match="no usable cells"):
        read_mesh(tmp_path / "cage.vtk", kind="volume")
