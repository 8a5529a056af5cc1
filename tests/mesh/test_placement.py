"""Rotations, placement order and box selection."""

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.placement import place, rotation_matrix, rotation_matrix_2d, select_in_box


def test_rotation_about_x_minus_90():
    r = rotation_matrix("x", -90)
    x = np.array([1.0, 2.0, 3.0])
    assert np.allclose(r @ x, [1.0, 3.0, -2.0])  # (x, y, z) -> (x, z, -y)
    assert np.allclose(rotation_matrix([2.0, 0, 0], -90), r)  # axis is normalised


def test_rotation_is_orthonormal_and_right_handed():
    r = rotation_matrix([1.0, 1.0, 0.3], 37.0)
    assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    assert np.allclose(rotation_matrix("z", 90) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(rotation_matrix_2d(90) @ [1, 0], [0, 1])


def test_place_order_scale_rotate_translate():
    v = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    out = place(v, scale=(2.0, 3.0, 1.0), rotations=[("z", 90), ("x", 90)], translation=(1, 1, 1))
    # scale: (2,0,0),(0,3,0); z90: (0,2,0),(-3,0,0); x90: (0,0,2),(-3,0,0); + t
    assert np.allclose(out, [[1, 1, 3], [-2, 1, 1]])
    assert np.allclose(v, [[1, 0, 0], [0, 1, 0]])  # input untouched


def test_place_2d():
    v = np.array([[1.0, 0.0]])
    assert np.allclose(place(v, scale=2.0, rotations=[90], translation=(0, 1)), [[0, 3]])
    assert np.allclose(place(v, rotations=[("z", 180)]), [[-1, 0]])
    with pytest.raises(MeshError):
        place(v, rotations=[("x", 90)])


def test_place_rejects_bad_input():
    with pytest.raises(MeshError):
        place(np.zeros((2, 3)), scale=(1, 2))
    with pytest.raises(MeshError):
        place(np.zeros((2, 3)), rotations=[("w", 10)])
    with pytest.raises(MeshError):
        place(np.zeros((2, 3)), translation=(1, 2))


def test_select_in_box_absolute_and_relative():
    g = np.stack(np.meshgrid(np.linspace(0, 2, 5), np.linspace(0, 1, 3), indexing="ij"), -1).reshape(-1, 2)
    top = select_in_box(g, (-10, 0.99), (10, 10))
    assert np.allclose(g[top, 1], 1.0) and top.size == 5 and top.dtype == np.int64
    bbox = (g.min(0), g.max(0))
    right = select_in_box(g, (0.75, 0.0), (1.0, 1.0), relative_to=bbox)
    assert np.all(g[right, 0] >= 1.5) and right.size == 6
    everything = select_in_box(g, (0, 0), (1, 1), relative_to=bbox)
    assert everything.size == g.shape[0]
