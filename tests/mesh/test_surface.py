"""Boundary extraction, edges, topology checks and enclosed volume."""

import numpy as np
import pytest

from idp.mesh.generate import box_surface, tet_box, tri_rectangle
from idp.mesh.surface import (
    boundary_faces,
    boundary_vertices,
    enclosed_volume,
    surface_topology,
    unique_edges,
)

UNIT_TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_single_tet_boundary_is_outward():
    faces = boundary_faces(np.array([[0, 1, 2, 3]]))
    assert faces.shape == (4, 3) and faces.dtype == np.int64
    assert enclosed_volume(UNIT_TET, faces) == pytest.approx(1 / 6)
    centroid = UNIT_TET.mean(axis=0)
    for f in faces:  # each face normal points away from the centroid
        a, b, c = UNIT_TET[f]
        assert np.dot(np.cross(b - a, c - a), a - centroid) > 0


def test_two_tets_share_a_face():
    v = np.vstack([UNIT_TET, [[1.0, 1.0, 1.0]]])
    elems = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    from idp.mesh.quality import signed_volumes

    elems[signed_volumes(v, elems) < 0] = elems[signed_volumes(v, elems) < 0][:, [1, 0, 2, 3]]
    faces = boundary_faces(elems)
    assert faces.shape == (6, 3)
    assert not any(set(f) == {1, 2, 3} for f in faces.tolist())
    assert enclosed_volume(v, faces) == pytest.approx(np.abs(signed_volumes(v, elems)).sum())


def test_tet_box_boundary_volume_equals_box():
    mesh = tet_box((0, 0, 0), (2, 3, 4), (2, 3, 4))
    faces = boundary_faces(mesh.elements)
    assert faces.shape[0] == 2 * 2 * (2 * 3 + 3 * 4 + 2 * 4)
    assert enclosed_volume(mesh.vertices, faces) == pytest.approx(24.0)
    topo = surface_topology(faces, mesh.num_vertices)
    assert topo.is_closed and topo.is_consistently_oriented and topo.num_components == 1
    assert boundary_vertices(faces).size == 3 * 4 * 5 - 1 * 2 * 3


def test_2d_boundary_edges_are_counter_clockwise():
    mesh = tri_rectangle((0, 0), (2, 1), (4, 2))
    edges = boundary_faces(mesh.elements)
    assert edges.shape == (2 * (4 + 2), 2)
    assert enclosed_volume(mesh.vertices, edges) == pytest.approx(2.0)
    topo = surface_topology(edges, mesh.num_vertices)
    assert topo.is_closed and topo.is_consistently_oriented


def test_unique_edges_of_a_closed_surface():
    s = box_surface(resolution=2)
    edges = unique_edges(s.faces)
    assert np.all(edges[:, 0] < edges[:, 1])
    assert edges.shape[0] == s.faces.shape[0] * 3 // 2
    assert len({tuple(e) for e in edges.tolist()}) == edges.shape[0]
    # Euler characteristic of a sphere
    assert s.num_vertices - edges.shape[0] + s.faces.shape[0] == 2


def test_topology_detects_open_surface():
    s = box_surface(resolution=2)
    topo = surface_topology(s.faces[1:], s.num_vertices)
    assert not topo.is_closed and topo.num_boundary_edges == 3
    assert topo.is_consistently_oriented


def test_topology_detects_nonmanifold_edge():
    s = box_surface(resolution=2)
    a, b, _ = s.faces[0]
    extra = np.vstack([s.vertices, [[5.0, 5.0, 5.0]]])
    faces = np.vstack([s.faces, [[a, b, s.num_vertices]]])
    topo = surface_topology(faces, extra.shape[0])
    assert topo.num_nonmanifold_edges == 1 and not topo.is_closed


def test_topology_detects_flipped_face():
    s = box_surface(resolution=2)
    faces = s.faces.copy()
    faces[5] = faces[5, [0, 2, 1]]
    topo = surface_topology(faces, s.num_vertices)
    assert topo.num_inconsistent_edges == 3 and not topo.is_consistently_oriented
    assert topo.is_closed


def test_topology_counts_components():
    s = box_surface(resolution=1)
    faces = np.vstack([s.faces, s.faces + s.num_vertices])
    assert surface_topology(faces, 2 * s.num_vertices).num_components == 2


def test_polyline_topology():
    ring = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    assert surface_topology(ring, 4).is_closed
    assert surface_topology(ring[:3], 4).num_boundary_edges == 2
    flipped = ring.copy()
    flipped[1] = [2, 1]
    topo = surface_topology(flipped, 4)
    assert topo.num_inconsistent_edges == 2 and not topo.is_consistently_oriented
    square = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
    assert enclosed_volume(square, ring) == pytest.approx(1.0)
    assert enclosed_volume(square, ring[:, ::-1]) == pytest.approx(-1.0)
