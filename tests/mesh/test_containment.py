"""Winding numbers of points w.r.t. closed boundaries (3D and 2D), including a body with a cavity."""

from __future__ import annotations

import numpy as np

from idp.mesh import generate as gen
from idp.mesh.containment import shielded, winding_numbers
from idp.mesh.surface import boundary_faces


def test_ball_inside_outside_and_cavity():
    ball = gen.tet_ball(radius=1.0, resolution=3)
    faces = boundary_faces(ball.elements)
    w = winding_numbers(np.array([[0.0, 0, 0], [0.3, -0.2, 0.1], [2.0, 0, 0], [0, 5, 1]]), ball.vertices, faces)
    np.testing.assert_allclose(w, [1, 1, 0, 0], atol=1e-9)
    # a shell with a cavity: outer boundary outward, inner boundary reversed (facing the cavity)
    inner = gen.tet_ball(radius=0.5, resolution=2)
    fi = boundary_faces(inner.elements)[:, ::-1] + ball.vertices.shape[0]
    V = np.vstack([ball.vertices, inner.vertices])
    w = winding_numbers(np.array([[0.0, 0, 0], [0.75, 0, 0]]), V, np.vstack([faces, fi]))
    np.testing.assert_allclose(w, [0, 1], atol=1e-9)


def test_polygon_2d():
    disk = gen.tri_disk(radius=1.0, resolution=3)
    segs = boundary_faces(disk.elements)
    w = winding_numbers(np.array([[0.0, 0.0], [0.5, 0.5], [1.5, 0.0]]), disk.vertices, segs)
    np.testing.assert_allclose(w, [1, 1, 0], atol=1e-9)


def test_shielded_by_a_closed_wrapper_not_by_a_bowl():
    # a hollow ball: points in its cavity are outside its material (winding 0) yet shielded on every side
    outer = gen.tet_ball(radius=1.0, resolution=3)
    inner = gen.tet_ball(radius=0.5, resolution=2)
    fo = boundary_faces(outer.elements)
    fi = boundary_faces(inner.elements)[:, ::-1] + outer.vertices.shape[0]
    V = np.vstack([outer.vertices, inner.vertices])
    cavity = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.15]])
    np.testing.assert_allclose(winding_numbers(cavity, V, np.vstack([fo, fi])), 0.0, atol=1e-9)
    assert shielded(cavity, V, np.vstack([fo, fi])).all()
    assert not shielded(np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 3.0]]), V, fo).any()
    # a bowl (the ball's faces below y = 0.2): a point above its floor sees the sky along +y
    cen = outer.vertices[fo].mean(axis=1)
    bowl = fo[cen[:, 1] < 0.2]
    assert not shielded(np.array([[0.0, 0.0, 0.0]]), outer.vertices, bowl).any()
