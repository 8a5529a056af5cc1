"""Every generator gives positive elements and closed, manifold, outward surfaces."""

import numpy as np
import pytest

from idp.contact.intersections import count_intersections
from idp.errors import MeshError
from idp.mesh.generate import (
    box_surface,
    cylinder_surface,
    hourglass_profile,
    hourglass_surface,
    polygon_box,
    polygon_circle,
    revolve_profile,
    tet_ball,
    tet_box,
    tet_ellipsoid,
    tri_disk,
    tri_rectangle,
)
from idp.mesh.quality import signed_volumes
from idp.mesh.surface import boundary_faces, enclosed_volume, surface_topology


def _closed_outward(vertices, faces):
    topo = surface_topology(faces, vertices.shape[0])
    assert topo.is_closed, topo
    assert topo.is_consistently_oriented, topo
    assert topo.num_components == 1
    vol = enclosed_volume(vertices, faces)
    assert vol > 0
    return vol


def _min_dihedral_degrees(v, e):
    p = v[e]
    normals = []
    for f in ([1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]):
        n = np.cross(p[:, f[1]] - p[:, f[0]], p[:, f[2]] - p[:, f[0]])
        normals.append(n / np.linalg.norm(n, axis=1)[:, None])
    cos = [np.einsum("ij,ij->i", normals[i], normals[j]) for i in range(4) for j in range(i + 1, 4)]
    return float(np.min(180.0 - np.degrees(np.arccos(np.clip(cos, -1, 1)))))


def test_tet_box():
    mesh = tet_box((-1, 0, 2), (1, 3, 3), (4, 6, 2))
    assert mesh.elements.shape == (6 * 4 * 6 * 2, 4) and mesh.dim == 3
    vol = signed_volumes(mesh.vertices, mesh.elements)
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(6.0)
    assert np.allclose(vol, vol[0])  # all Kuhn tets of a uniform grid are congruent
    assert _closed_outward(mesh.vertices, boundary_faces(mesh.elements)) == pytest.approx(6.0)
    assert np.allclose(mesh.vertices.min(0), [-1, 0, 2]) and np.allclose(mesh.vertices.max(0), [1, 3, 3])


@pytest.mark.parametrize("resolution", [1, 2, 6])
def test_tet_ball_quality_and_volume(resolution):
    mesh = tet_ball(2.0, (1.0, -1.0, 0.5), resolution)
    vol = signed_volumes(mesh.vertices, mesh.elements)
    assert np.all(vol > 0)
    assert vol.min() > 0.5 * vol.mean()
    assert _min_dihedral_degrees(mesh.vertices, mesh.elements) > 25.0
    faces = boundary_faces(mesh.elements)
    exact = 4 / 3 * np.pi * 8.0
    enclosed = _closed_outward(mesh.vertices, faces)
    assert enclosed == pytest.approx(vol.sum())
    if resolution == 6:
        assert enclosed == pytest.approx(exact, rel=0.02)
        assert count_intersections(mesh.vertices, faces) == 0
    r = np.linalg.norm(mesh.vertices[np.unique(faces)] - [1.0, -1.0, 0.5], axis=1)
    assert np.allclose(r, 2.0)  # boundary vertices lie on the sphere


def test_tet_ellipsoid_volume():
    mesh = tet_ellipsoid((1.0, 0.5, 2.0), resolution=6)
    vol = signed_volumes(mesh.vertices, mesh.elements)
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(4 / 3 * np.pi * 1.0, rel=0.02)
    assert np.allclose(mesh.vertices.max(0), [1.0, 0.5, 2.0])


def test_box_surface():
    s = box_surface((0, 0, 0), (1, 2, 3), resolution=3)
    assert s.faces.shape == (6 * 9 * 2, 3)
    assert s.num_vertices == 6 * 16 - 12 * 4 + 8  # welded edges and corners
    assert _closed_outward(s.vertices, s.faces) == pytest.approx(6.0)
    assert count_intersections(s.vertices, s.faces) == 0


def test_cylinder_surface_volume_is_exact_prism():
    segs = 24
    s = cylinder_surface(radius=0.5, y0=-1.0, y1=1.0, segments=segs, rings=5, cap_rings=3)
    polygon_area = 0.5 * segs * 0.25 * np.sin(2 * np.pi / segs)
    assert _closed_outward(s.vertices, s.faces) == pytest.approx(polygon_area * 2.0)
    assert np.allclose(s.vertices.min(0), [-0.5, -1.0, -0.5], atol=1e-12)
    assert count_intersections(s.vertices, s.faces) == 0


def test_hourglass_shape():
    s = hourglass_surface(bulb_radius=0.5, neck_radius=0.15, lower_center=0.0, upper_center=1.6)
    assert count_intersections(s.vertices, s.faces) == 0
    vol = _closed_outward(s.vertices, s.faces)
    lo, hi = s.vertices.min(0), s.vertices.max(0)
    assert lo[1] == pytest.approx(-0.5) and hi[1] == pytest.approx(2.1)
    assert np.allclose([hi[0], hi[2], -lo[0], -lo[2]], 0.5)  # equators are sampled exactly
    # Narrow neck: a ring of radius neck_radius at the middle height, nothing thinner.
    radial = np.hypot(s.vertices[:, 0], s.vertices[:, 2])
    middle = np.abs(s.vertices[:, 1] - 0.8) < 1e-12
    assert middle.sum() == 32 and np.allclose(radial[middle], 0.15)
    assert radial[np.abs(s.vertices[:, 1] - 0.8) < 0.3].min() == pytest.approx(0.15)
    # Volume of revolution of the profile, by quadrature.
    ys, rs = hourglass_profile(0.5, 0.15, 0.0, 1.6, samples=20001)
    exact = np.pi * np.sum(0.5 * (rs[1:] ** 2 + rs[:-1] ** 2) * np.diff(ys))
    assert vol == pytest.approx(exact, rel=0.02)


def test_hourglass_profile_is_c1():
    ys, rs = hourglass_profile(samples=4001)
    assert ys.size == 4001 and np.all(np.diff(ys) > 0)
    slope = np.diff(rs) / np.diff(ys)
    inner = slope[200:-200]  # away from the poles, where the slope is infinite
    assert np.max(np.abs(np.diff(inner))) < 0.05


def test_revolve_profile_open_tube_is_outward():
    s = revolve_profile([0.0, 1.0], [1.0, 1.0], 16)
    topo = surface_topology(s.faces, s.num_vertices)
    assert topo.num_boundary_edges == 32 and topo.is_consistently_oriented
    a, b, c = s.vertices[s.faces[0]]
    n = np.cross(b - a, c - a)
    assert np.dot(n, (a + b + c) / 3 * [1, 0, 1]) > 0


def test_tri_rectangle():
    mesh = tri_rectangle((0, 0), (3, 1), (6, 2))
    assert mesh.dim == 2 and mesh.elements.shape == (24, 3)
    area = signed_volumes(mesh.vertices, mesh.elements)
    assert np.all(area > 0) and area.sum() == pytest.approx(3.0)
    assert _closed_outward(mesh.vertices, boundary_faces(mesh.elements)) == pytest.approx(3.0)


def test_tri_disk():
    mesh = tri_disk(2.0, (1.0, 1.0), resolution=6)
    area = signed_volumes(mesh.vertices, mesh.elements)
    assert np.all(area > 0) and area.min() > 0.5 * area.mean()
    edges = boundary_faces(mesh.elements)
    assert _closed_outward(mesh.vertices, edges) == pytest.approx(4 * np.pi, rel=0.01)
    assert np.allclose(np.linalg.norm(mesh.vertices[np.unique(edges)] - 1.0, axis=1), 2.0)


def test_polygons_are_counter_clockwise():
    c = polygon_circle(1.5, (0.5, 0.0), segments=32)
    assert c.faces.shape == (32, 2)
    assert _closed_outward(c.vertices, c.faces) == pytest.approx(0.5 * 32 * 1.5**2 * np.sin(2 * np.pi / 32))
    b = polygon_box((0, 0), (2, 1), resolution=(4, 2))
    assert b.faces.shape == (12, 2)
    assert _closed_outward(b.vertices, b.faces) == pytest.approx(2.0)


def test_bad_arguments():
    with pytest.raises(MeshError):
        tet_box((0, 0, 0), (1, -1, 1))
    with pytest.raises(MeshError):
        tet_ball(resolution=0)
    with pytest.raises(MeshError):
        hourglass_surface(neck_radius=0.6)
