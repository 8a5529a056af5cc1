"""Signed volumes and the inverted / degenerate queries."""

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.quality import degenerate_elements, inverted_elements, signed_volumes

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
