"""Surface-preserving remeshing with TetGen (the optional ``idp[remesh]`` extra).

The one test that runs without TetGen (the install hint) is in test_remesh_unavailable.py.
"""

import numpy as np
import pytest

pytest.importorskip("tetgen", reason="surface-preserving remeshing needs idp[remesh]")

from idp.errors import MeshError
from idp.mesh.generate import tet_ball, tet_box
from idp.mesh.quality import signed_volumes
from idp.mesh.remesh import RemeshResult, mesher_available, remesh_volume
from idp.mesh.surface import boundary_faces, boundary_vertices
from idp.mesh.transfer import transfer_cell_data, transfer_rest_frames


def _triangle_set(x, faces):
    """Boundary triangles as a set of (sorted) coordinate triples: independent of the numbering."""
    return {tuple(sorted(tuple(x[i]) for i in f)) for f in faces}


def _frames(x, elements):
    xe = x[elements]
    return np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1))


def _check_valid(v, e, r: RemeshResult):
    vol = signed_volumes(r.vertices, r.elements)
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(signed_volumes(v, e).sum(), rel=1e-10)
    bv = boundary_vertices(boundary_faces(e))
    assert np.all(r.boundary_map[bv] >= 0)
    assert np.count_nonzero(r.boundary_map >= 0) == bv.size
    # bitwise equal positions
    assert np.array_equal(r.vertices[r.boundary_map[bv]].view(np.int64), v[bv].view(np.int64))
    assert r.quality_after.min_dihedral > 0
    assert r.quality_after.num_elements == len(r.elements)
    assert r.quality_before.num_elements == len(e)


@pytest.mark.parametrize("mesh", [tet_ball(resolution=3), tet_box(resolution=3)], ids=["ball", "box"])
def test_boundary_is_kept_exactly(mesh):
    assert mesher_available()
    v, e = mesh.vertices, mesh.elements
    r = remesh_volume(v, e)
    _check_valid(v, e, r)
    old_faces, new_faces = boundary_faces(e), boundary_faces(r.elements)
    # same triangles, same orientation, through the map ...
    mapped = r.boundary_map[old_faces]
    assert {tuple(np.roll(f, -np.argmin(f))) for f in mapped} == {tuple(np.roll(f, -np.argmin(f))) for f in new_faces}
    # ... and as coordinate triples
    assert _triangle_set(v, old_faces) == _triangle_set(r.vertices, new_faces)
    assert "Y" in r.switches and r.switches.startswith("pq1.414")
    assert r.quality_before.to_dict()["num_elements"] == len(e)


def test_max_volume_makes_more_elements():
    mesh = tet_box(resolution=3)
    coarse = remesh_volume(mesh.vertices, mesh.elements)
    fine = remesh_volume(mesh.vertices, mesh.elements, max_volume=0.01)
    assert len(fine.elements) > len(coarse.elements)
    # with Y the bound is a target: TetGen leaves a tet larger rather than encroach on the boundary
    assert np.median(signed_volumes(fine.vertices, fine.elements)) <= 0.01
    _check_valid(mesh.vertices, mesh.elements, fine)
    dihedral = remesh_volume(mesh.vertices, mesh.elements, quality=1.2, min_dihedral=10.0)
    assert "q1.2/10" in dihedral.switches
    _check_valid(mesh.vertices, mesh.elements, dihedral)


def test_refine_surface_splits_triangles_in_their_plane():
    mesh = tet_box(resolution=2)
    v, e = mesh.vertices, mesh.elements
    r = remesh_volume(v, e, refine_surface=True, max_volume=0.002)
    _check_valid(v, e, r)
    assert "Y" not in r.switches
    new_bv = boundary_vertices(boundary_faces(r.elements))
    assert new_bv.size > np.count_nonzero(r.boundary_map >= 0)  # TetGen did add surface points
    assert np.all(np.isclose(np.abs(r.vertices[new_bv]), 1.0, rtol=0, atol=1e-12).any(axis=1))  # on a box face


def test_refine_surface_on_a_curved_surface():
    mesh = tet_ball(resolution=3)
    r = remesh_volume(mesh.vertices, mesh.elements, refine_surface=True, max_volume=0.002)
    _check_valid(mesh.vertices, mesh.elements, r)


def _hollow_ball():
    m = tet_ball(resolution=3)
    keep = m.elements[np.linalg.norm(m.vertices[m.elements].mean(axis=1), axis=1) > 0.45]
    used = np.unique(keep)
    renumber = np.full(len(m.vertices), -1)
    renumber[used] = np.arange(used.size)
    return m.vertices[used], renumber[keep]


def test_cavity_and_nested_shell_stay_empty():
    v, e = _hollow_ball()
    r = remesh_volume(v, e)
    _check_valid(v, e, r)
    inner = tet_ball(radius=0.2, resolution=1)
    v2, e2 = np.vstack([v, inner.vertices]), np.vstack([e, inner.elements + len(v)])
    r2 = remesh_volume(v2, e2)
    _check_valid(v2, e2, r2)
    assert _triangle_set(v2, boundary_faces(e2)) == _triangle_set(r2.vertices, boundary_faces(r2.elements))
    with pytest.raises(MeshError, match="cavity"):
        remesh_volume(v, e, refine_surface=True)


def test_bad_input_is_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # TetGen's files for a self-intersecting surface must not land here
    box = tet_box(resolution=1)
    v, e = box.vertices, box.elements
    with pytest.raises(MeshError, match="inverted"):
        remesh_volume(v, np.vstack([e[:1, [1, 0, 2, 3]], e[1:]]))
    # a third tet on an interior face of the box: that face is shared by three tets
    faces = np.sort(e[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    inner = uniq[np.flatnonzero(counts == 2)[0]]
    v_far = np.vstack([v, [5.0, 6.0, 7.0]])
    extra = np.array([[*inner, len(v)]])
    if signed_volumes(v_far, extra)[0] < 0:
        extra = extra[:, [1, 0, 2, 3]]
    with pytest.raises(MeshError, match="shared by more than two"):
        remesh_volume(v_far, np.vstack([e, extra]))
    # two tets touching along one edge only: a non-manifold boundary
    t = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1]])
    edge_only = np.array([[0, 1, 2, 3], [1, 0, 5, 4]])
    assert np.all(signed_volumes(t, edge_only) > 0)
    with pytest.raises(MeshError, match="non-manifold boundary"):
        remesh_volume(t, edge_only)
    overlap = tet_ball(resolution=1)
    v2 = np.vstack([overlap.vertices, overlap.vertices + 0.5])
    with pytest.raises(MeshError, match="self-intersect"):
        remesh_volume(v2, np.vstack([overlap.elements, overlap.elements + len(overlap.vertices)]))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="max_volume"):
        remesh_volume(v, e, max_volume=-1.0)


def test_affine_state_is_kept_by_remesh_and_transfer():
    mesh = tet_ball(resolution=3)
    A = np.array([[1.4, 0.3, 0.0], [-0.2, 0.9, 0.25], [0.1, -0.3, 1.2]])
    assert np.linalg.det(A) > 0
    x = mesh.vertices @ A.T + np.array([1.0, -2.0, 0.5])
    rest = _frames(mesh.vertices, mesh.elements)
    r = remesh_volume(x, mesh.elements, max_volume=0.01)
    dm = transfer_rest_frames(x, mesh.elements, rest, r.vertices, r.elements)
    F = _frames(r.vertices, r.elements) @ np.linalg.inv(dm)
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), rtol=0, atol=1e-10 * np.abs(A).max())
    # a per-element attribute that is 1 on one side of the plane X = 0 and 2 on the other
    cx = mesh.vertices[mesh.elements].mean(axis=1)[:, 0]
    out = transfer_cell_data(x, mesh.elements, r.vertices, r.elements, {"side": np.where(cx < 0, 1, 2)})
    rest_cx = np.linalg.solve(A, (r.vertices[r.elements].mean(axis=1) - [1.0, -2.0, 0.5]).T)[0]
    clear = np.abs(rest_cx) > 0.4  # farther from the plane than one input element
    assert clear.sum() > 10
    np.testing.assert_array_equal(out["side"][clear], np.where(rest_cx[clear] < 0, 1, 2))
