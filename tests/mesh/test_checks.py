"""check_mesh: reports on good and broken files."""

import meshio
import numpy as np

from idp.mesh.checks import check_mesh
from idp.mesh.generate import box_surface, hourglass_surface, tet_ball, tri_disk
from idp.mesh.io import write_mesh
from idp.mesh.types import SurfaceMesh


def test_generated_files_are_ok(tmp_path):
    for name, mesh in (
        ("ball.msh", tet_ball(resolution=3)),
        ("disk.vtk", tri_disk(resolution=3)),
        ("hourglass.obj", hourglass_surface()),
    ):
        rep = check_mesh(tmp_path / name)
        assert rep.kind == "unreadable"
        write_mesh(tmp_path / name, mesh)
        rep = check_mesh(tmp_path / name)
        assert rep.ok, rep.format()
        assert rep.topology.is_closed and rep.num_intersecting_pairs == 0
        assert rep.enclosed_volume > 0
        assert "OK" in rep.format()
    assert check_mesh(tmp_path / "disk.vtk").dim == 2


def test_intersecting_surface_is_reported(tmp_path):
    a = box_surface(resolution=2)
    v = np.vstack([a.vertices, a.vertices + 0.5])
    f = np.vstack([a.faces, a.faces + a.num_vertices])
    write_mesh(tmp_path / "two.stl", SurfaceMesh(v, f))
    rep = check_mesh(tmp_path / "two.stl")
    assert not rep.ok and rep.num_intersecting_pairs > 0
    assert rep.topology.num_components == 2
    assert f"{rep.num_intersecting_pairs} intersecting edge-triangle pairs" in rep.format()


def test_mixed_orientation_reports_minority(tmp_path):
    ball = tet_ball(resolution=2)
    elems = ball.elements.copy()
    elems[[3, 8]] = elems[[3, 8]][:, [1, 0, 2, 3]]
    meshio.Mesh(ball.vertices, [("tetra", elems)]).write(str(tmp_path / "mixed.vtu"))
    rep = check_mesh(tmp_path / "mixed.vtu")
    assert rep.num_inverted == 2 and not rep.ok
    assert any("3, 8" in p for p in rep.problems)
    assert rep.topology.is_closed  # boundary is still built from re-oriented elements
    # all-negative is only a note: idp flips those on load
    meshio.Mesh(ball.vertices, [("tetra", ball.elements[:, [1, 0, 2, 3]])]).write(str(tmp_path / "neg.vtu"))
    rep = check_mesh(tmp_path / "neg.vtu")
    assert rep.ok and rep.num_inverted == 0 and rep.notes


def test_open_and_flipped_surfaces(tmp_path):
    s = box_surface(resolution=2)
    write_mesh(tmp_path / "open.obj", SurfaceMesh(s.vertices, s.faces[1:]))
    rep = check_mesh(tmp_path / "open.obj")
    assert rep.ok and rep.topology.num_boundary_edges == 3 and "open surface" in rep.notes[0]
    faces = s.faces.copy()
    faces[0] = faces[0, ::-1]
    write_mesh(tmp_path / "flip.obj", SurfaceMesh(s.vertices, faces))
    rep = check_mesh(tmp_path / "flip.obj")
    assert not rep.ok and rep.topology.num_inconsistent_edges == 3


def test_degenerate_element_counted(tmp_path):
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.3, 0.3, 0.0]])
    meshio.Mesh(pts, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 4]]))]).write(str(tmp_path / "d.vtu"))
    rep = check_mesh(tmp_path / "d.vtu")
    assert rep.num_degenerate == 1 and not rep.ok
    assert "degenerate" in rep.format()
