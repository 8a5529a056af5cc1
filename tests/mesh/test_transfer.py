"""Point location and per-element transfer between two meshes of the same region (no mesher needed)."""

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.generate import tet_box, tri_rectangle
from idp.mesh.transfer import locate_points, transfer_cell_data, transfer_rest_frames

A = np.array([[1.3, 0.2, -0.1], [0.1, 0.8, 0.3], [-0.2, 0.1, 1.1]])
B = np.array([0.5, -2.0, 3.0])


def _frames(x, elements):
    xe = x[elements]
    return np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1))


def test_locate_points_finds_containing_element():
    mesh = tet_box(resolution=3)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.99, 0.99, size=(500, 3))
    loc = locate_points(mesh.vertices, mesh.elements, pts)
    xe = mesh.vertices[mesh.elements[loc]]
    lam = np.linalg.solve(np.transpose(xe[:, 1:] - xe[:, :1], (0, 2, 1)), (pts - xe[:, 0])[:, :, None])[:, :, 0]
    assert np.all(lam >= -1e-12) and np.all(lam.sum(axis=1) <= 1 + 1e-12)
    # the centroids locate to their own elements
    own = locate_points(mesh.vertices, mesh.elements, mesh.vertices[mesh.elements].mean(axis=1), k=1)
    np.testing.assert_array_equal(own, np.arange(len(mesh.elements)))


def test_points_just_outside_get_the_adjacent_element():
    mesh = tet_box(resolution=2)
    pts = np.array([[1.0 + 1e-13, 0.3, 0.2], [0.3, -1.0 - 1e-13, -0.7]])
    loc = locate_points(mesh.vertices, mesh.elements, pts)
    inside = locate_points(mesh.vertices, mesh.elements, pts * np.array([[1 - 1e-6, 1, 1], [1, 1 - 1e-6, 1]]))
    np.testing.assert_array_equal(loc, inside)


def test_affine_deformation_gradient_survives_transfer():
    old = tet_box(resolution=2)
    new = tet_box(resolution=(3, 4, 5))
    rest = _frames(old.vertices, old.elements)  # rest shape = the undeformed box
    x_old = old.vertices @ A.T + B  # current shape: x = A X + b
    x_new = new.vertices @ A.T + B  # the new mesh of the current shape
    dm_new = transfer_rest_frames(x_old, old.elements, rest, x_new, new.elements)
    F = _frames(x_new, new.elements) @ np.linalg.inv(dm_new)
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), rtol=0, atol=1e-10 * np.abs(A).max())
    assert np.all(np.linalg.det(dm_new) > 0)


def test_cell_data_is_piecewise_constant():
    old = tet_box(resolution=4)
    new = tet_box(resolution=(3, 5, 7))
    cx = old.vertices[old.elements].mean(axis=1)[:, 0]
    value = np.where(cx < 0, 1.0, 2.0)
    tensor = np.repeat(np.eye(3)[None], len(cx), axis=0) * value[:, None, None]
    out = transfer_cell_data(old.vertices, old.elements, new.vertices, new.elements, {"v": value, "t": tensor})
    ncx = new.vertices[new.elements].mean(axis=1)[:, 0]
    clear = np.abs(ncx) > 0.5 / 3  # farther from x = 0 than one old cell
    np.testing.assert_array_equal(out["v"][clear], np.where(ncx[clear] < 0, 1.0, 2.0))
    assert out["t"].shape == (len(new.elements), 3, 3)
    np.testing.assert_array_equal(out["t"][:, 0, 0], out["v"])


def test_transfer_in_2d():
    old = tri_rectangle(resolution=3)
    new = tri_rectangle(resolution=(5, 4))
    A2 = np.array([[1.1, 0.4], [-0.2, 0.9]])
    dm_new = transfer_rest_frames(
        old.vertices @ A2.T, old.elements, _frames(old.vertices, old.elements), new.vertices @ A2.T, new.elements
    )
    F = _frames(new.vertices @ A2.T, new.elements) @ np.linalg.inv(dm_new)
    np.testing.assert_allclose(F, np.broadcast_to(A2, F.shape), atol=1e-12)


def test_bad_shapes_are_errors():
    mesh = tet_box(resolution=1)
    with pytest.raises(MeshError, match="one row per old element"):
        transfer_cell_data(mesh.vertices, mesh.elements, mesh.vertices, mesh.elements, {"a": np.zeros(3)})
    with pytest.raises(MeshError, match="old_rest_frames"):
        transfer_rest_frames(mesh.vertices, mesh.elements, np.zeros((1, 3, 3)), mesh.vertices, mesh.elements)
    with pytest.raises(MeshError, match=r"points must be \(q, 3\)"):
        locate_points(mesh.vertices, mesh.elements, np.zeros((2, 2)))
