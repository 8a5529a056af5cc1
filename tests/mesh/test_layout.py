"""Instancing layouts: grid, ring and seeded random transforms (idp.mesh.layout)."""

from __future__ import annotations

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.layout import (
    explicit_transform,
    grid_transforms,
    random_transforms,
    ring_basis,
    ring_transforms,
)
from idp.mesh.placement import rotation_matrix


def assert_rotations(r: np.ndarray) -> None:
    """Every matrix orthonormal with determinant 1."""
    eye = np.eye(r.shape[1])
    for m in r:
        np.testing.assert_allclose(m @ m.T, eye, atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)


def test_grid_counts_and_order() -> None:
    lin, t = grid_transforms([3, 2, 2], [1.0, 2.0, 4.0], origin=[10.0, 0.0, 0.0])
    assert lin.shape == (12, 3, 3) and t.shape == (12, 3)
    np.testing.assert_array_equal(lin, np.broadcast_to(np.eye(3), (12, 3, 3)))
    # x fastest, then y, then z: k = i + nx * (j + ny * l)
    np.testing.assert_allclose(t[0], [10, 0, 0])
    np.testing.assert_allclose(t[1], [11, 0, 0])
    np.testing.assert_allclose(t[3], [10, 2, 0])
    np.testing.assert_allclose(t[6], [10, 0, 4])
    np.testing.assert_allclose(t[11], [12, 2, 4])
    lin2, t2 = grid_transforms([2, 3], [0.5, 0.5])
    assert lin2.shape == (6, 2, 2) and len(np.unique(t2, axis=0)) == 6


def test_ring_radii_and_angles_3d() -> None:
    center = np.array([1.0, 2.0, 3.0])
    lin, t = ring_transforms(8, 2.5, center.tolist(), axis=[0, 0, 1], start_degrees=10.0)
    assert lin.shape == (8, 3, 3)
    assert_rotations(lin)
    rel = t - center
    np.testing.assert_allclose(np.linalg.norm(rel, axis=1), 2.5)
    np.testing.assert_allclose(rel[:, 2], 0.0, atol=1e-12)  # in the plane perpendicular to the axis
    phi = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))  # axis z: u = x, v = y
    np.testing.assert_allclose(np.mod(phi - 10.0 + 1e-9, 360.0) - 1e-9, np.arange(8) * 45.0, atol=1e-9)
    # face_center: the copy at phi is the copy at 0 turned by phi about the ring's axis through the centre
    for k in range(8):
        turn = lin[k] @ np.linalg.inv(lin[0])
        np.testing.assert_allclose(turn @ rel[0], rel[k], atol=1e-12)


def test_ring_without_face_center_only_translates() -> None:
    lin, _ = ring_transforms(5, 1.0, [0, 0, 0], face_center=False)
    np.testing.assert_allclose(lin, np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-15)
    lin, _ = ring_transforms(5, 1.0, [0, 0, 0], face_center=False, rotate_offset_degrees=30)
    for m in lin:
        np.testing.assert_allclose(m, rotation_matrix("y", 30), atol=1e-15)


def test_ring_reproduces_the_rhododendron_convention() -> None:
    """Paper §7.5: rotated about +y by (-90 - phi), translated to (r cos phi, 0, r sin phi)."""
    r, n, start = 0.7, 5, 12.0
    lin, t = ring_transforms(n, r, [0, 0, 0], axis=[0, -1, 0], start_degrees=start, rotate_offset_degrees=90)
    for k in range(n):
        phi = start + k * 360.0 / n
        p = np.radians(phi)
        np.testing.assert_allclose(t[k], [r * np.cos(p), 0.0, r * np.sin(p)], atol=1e-12)
        np.testing.assert_allclose(lin[k], rotation_matrix("y", -90.0 - phi), atol=1e-12)


def test_ring_basis_is_right_handed() -> None:
    for axis in ([0, 1, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1, 2, -3]):
        a, u, v = ring_basis(axis)
        np.testing.assert_allclose(np.cross(u, v), a, atol=1e-12)
        assert abs(u @ a) < 1e-12 and np.linalg.norm(u) == pytest.approx(1.0)
    np.testing.assert_allclose(ring_basis([0, 1, 0])[1], [1, 0, 0])
    with pytest.raises(MeshError, match="not all zero"):
        ring_basis([0, 0, 0])


def test_ring_2d() -> None:
    lin, t = ring_transforms(4, 2.0, [1.0, 0.0], start_degrees=90)
    assert lin.shape == (4, 2, 2)
    assert_rotations(lin)
    np.testing.assert_allclose(t, [[1, 2], [-1, 0], [1, -2], [3, 0]], atol=1e-12)
    # each copy turned counter-clockwise by its angle
    np.testing.assert_allclose(lin[0], [[0, -1], [1, 0]], atol=1e-12)
    with pytest.raises(MeshError, match="no axis"):
        ring_transforms(4, 1.0, [0.0, 0.0], axis=[0, 0, 1])


def test_random_is_reproducible_and_seeds_differ() -> None:
    lo, hi = [-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]
    a = random_transforms(20, 7, lo, hi)
    b = random_transforms(20, 7, lo, hi)
    np.testing.assert_array_equal(a[0], b[0])  # bit for bit
    np.testing.assert_array_equal(a[1], b[1])
    c = random_transforms(20, 8, lo, hi)
    assert not np.allclose(a[1], c[1]) and not np.allclose(a[0], c[0])
    assert_rotations(a[0])
    assert np.all(a[1] >= [-1, 0, -1]) and np.all(a[1] <= [1, 2, 1])
    # copy k does not depend on the count: a longer layout extends a shorter one
    short = random_transforms(5, 7, lo, hi)
    np.testing.assert_array_equal(short[0], a[0][:5])
    np.testing.assert_array_equal(short[1], a[1][:5])


def test_random_axis_angles_and_scales() -> None:
    lin, _ = random_transforms(
        50, 3, [0, 0, 0], [1, 1, 1], rotate_axis=[0, 0, 2], degrees_lo=10, degrees_hi=20, scale_lo=0.5, scale_hi=2
    )
    s = np.cbrt(np.linalg.det(lin))
    assert np.all((s >= 0.5) & (s <= 2.0)) and np.ptp(s) > 0.5
    rot = lin / s[:, None, None]
    assert_rotations(rot)
    np.testing.assert_allclose(rot[:, 2, 2], 1.0)  # about z
    deg = np.degrees(np.arctan2(rot[:, 1, 0], rot[:, 0, 0]))
    assert np.all((deg >= 10 - 1e-9) & (deg <= 20 + 1e-9))


def test_random_2d() -> None:
    lin, t = random_transforms(10, 1, [0, 0], [3, 3])
    assert lin.shape == (10, 2, 2) and t.shape == (10, 2)
    assert_rotations(lin)
    with pytest.raises(MeshError, match="2D"):
        random_transforms(3, 1, [0, 0], [1, 1], rotate_axis=[0, 0, 1])


def test_explicit_transform_order() -> None:
    lin, t = explicit_transform(3, [2.0, 1.0, 1.0], [([0, 0, 1], 90.0)], [0.0, 0.0, 5.0])
    x = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(lin @ x + t, [0.0, 2.0, 5.0], atol=1e-12)  # scaled, then turned, then moved
