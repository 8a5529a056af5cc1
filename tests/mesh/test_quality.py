"""Signed volumes and the inverted / degenerate queries."""

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.quality import (
    degenerate_elements,
    dihedral_angles,
    inverted_elements,
    mesh_quality,
    radius_ratios,
    signed_volumes,
)

UNIT_TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_unit_tet_volume_and_sign():
    assert signed_volumes(UNIT_TET, np.array([[0, 1, 2, 3]])) == pytest.approx([1 / 6])
    assert signed_volumes(UNIT_TET, np.array([[1, 0, 2, 3]])) == pytest.approx([-1 / 6])


def test_triangle_area_ccw_positive():
    v = np.array([[0.0, 0], [2, 0], [0, 1]])
    assert signed_volumes(v, np.array([[0, 1, 2], [0, 2, 1]])) == pytest.approx([1.0, -1.0])


def test_inverted_and_degenerate_indices():
    v = np.vstack([UNIT_TET, [[0.5, 0.5, 0.0]]])
    elems = np.array([[0, 1, 2, 3], [1, 0, 2, 3], [0, 1, 2, 4]])  # last one is flat
    assert inverted_elements(v, elems).tolist() == [1, 2]
    assert degenerate_elements(v, elems).tolist() == [2]
    assert inverted_elements(v, elems).dtype == np.int64


def test_shape_mismatch_is_an_error():
    with pytest.raises(MeshError, match=r"\(m, 4\)"):
        signed_volumes(UNIT_TET, np.array([[0, 1, 2]]))


REGULAR_TET = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])


def test_regular_tet_is_perfect():
    elems = np.array([[0, 1, 2, 3]])
    if signed_volumes(REGULAR_TET, elems)[0] < 0:
        elems = elems[:, [0, 2, 1, 3]]
    angles = dihedral_angles(REGULAR_TET, elems)
    assert angles.shape == (1, 6)
    np.testing.assert_allclose(angles, np.degrees(np.arccos(1 / 3)), rtol=1e-12)
    assert radius_ratios(REGULAR_TET, elems) == pytest.approx([1.0], rel=1e-12)
    # orientation does not matter
    np.testing.assert_allclose(dihedral_angles(REGULAR_TET, elems[:, [1, 0, 2, 3]]), angles[:, [0, 3, 4, 1, 2, 5]])
    assert radius_ratios(REGULAR_TET, elems[:, [1, 0, 2, 3]]) == pytest.approx([1.0], rel=1e-12)


def test_unit_corner_tet_angles():
    # three right angles at the edges through the origin, arccos(1/sqrt(3)) at the others
    angles = dihedral_angles(UNIT_TET, np.array([[0, 1, 2, 3]]))[0]
    np.testing.assert_allclose(angles[:3], 90.0, rtol=1e-12)
    np.testing.assert_allclose(angles[3:], np.degrees(np.arccos(1 / np.sqrt(3))), rtol=1e-12)


def test_sliver_has_ratio_near_zero():
    # four nearly coplanar points: a square with two opposite corners lifted by 1e-6
    sliver = np.array([[0.0, 0, 0], [1, 1, 0], [1, 0, 1e-6], [0, 1, 1e-6]])
    elems = np.array([[0, 1, 2, 3]])
    if signed_volumes(sliver, elems)[0] < 0:
        elems = elems[:, [0, 2, 1, 3]]
    assert radius_ratios(sliver, elems)[0] < 1e-5
    angles = dihedral_angles(sliver, elems)[0]
    assert angles.min() < 1e-3 and angles.max() > 180 - 1e-3
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert radius_ratios(flat, elems)[0] == 0.0


def test_mesh_quality_summary():
    v = np.vstack([REGULAR_TET, UNIT_TET + 5])
    elems = np.array([[0, 2, 1, 3], [4, 5, 6, 7]])
    if signed_volumes(v, elems[:1])[0] < 0:
        elems[0] = elems[0, [0, 2, 1, 3]]
    q = mesh_quality(v, elems)
    assert q.num_elements == 2
    assert q.min_dihedral == pytest.approx(np.degrees(np.arccos(1 / np.sqrt(3))))
    assert q.max_dihedral == pytest.approx(90.0)
    assert q.min_radius_ratio == pytest.approx(float(radius_ratios(UNIT_TET, elems[1:] - 4)[0]))
    assert q.mean_radius_ratio == pytest.approx((1 + q.min_radius_ratio) / 2)
    assert set(q.to_dict()) == {"min_dihedral", "max_dihedral", "mean_radius_ratio", "min_radius_ratio", "num_elements"}
    assert mesh_quality(v, np.zeros((0, 4), dtype=np.int64)).num_elements == 0
