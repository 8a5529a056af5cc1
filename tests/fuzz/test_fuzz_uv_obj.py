"""Fuzzing ``idp.mesh.uv_obj.read_uv_obj``: cut-cylinder OBJ files with a UV layout, mutated.

Property: ``read_uv_obj`` raises an :class:`idp.errors.IdpError` or returns a layout whose positions and UV
coordinates are finite and whose ``v`` / ``vt`` indices are in range, one line number per triangle.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from fuzz.common import fuzz, mutated_bytes
from hypothesis import given
from hypothesis import strategies as st

from idp.errors import IdpError
from idp.mesh.uv_obj import UVMesh, cut_cylinder_obj_text, read_uv_obj


def assert_valid_uv_mesh(m: UVMesh) -> None:
    assert m.positions.dtype == np.float64 and m.positions.ndim == 2 and m.positions.shape[1] == 3
    assert m.uv.dtype == np.float64 and m.uv.ndim == 2 and m.uv.shape[1] == 2
    assert np.isfinite(m.positions).all() and np.isfinite(m.uv).all(), "accepted non-finite coordinates"
    assert m.faces_xyz.shape == m.faces_uv.shape and m.faces_xyz.ndim == 2 and m.faces_xyz.shape[1] == 3
    assert m.faces_xyz.shape[0] > 0 and m.face_lines.shape == (m.faces_xyz.shape[0],)
    assert 0 <= m.faces_xyz.min() and m.faces_xyz.max() < m.positions.shape[0], "v index out of range"
    assert 0 <= m.faces_uv.min() and m.faces_uv.max() < m.uv.shape[0], "vt index out of range"


def _read(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "uv.obj"
        path.write_bytes(data)
        try:
            mesh = read_uv_obj(path)
        except IdpError as exc:
            assert str(exc)
            return
        assert_valid_uv_mesh(mesh)


@fuzz(500)
@given(
    segments=st.integers(3, 6),
    rings=st.integers(1, 2),
    newline=st.sampled_from(["\n", "\r\n", "\r"]),
    w=st.booleans(),
    data=st.data(),
)
def test_uv_obj_mutated(segments, rings, newline, w, data):
    base = cut_cylinder_obj_text(segments, rings, newline=newline, w=w).encode()
    _read(data.draw(mutated_bytes(base), label="file"))


@fuzz(60)
@given(data=st.binary(max_size=512))
def test_uv_obj_random_bytes(data):
    _read(data)


@pytest.mark.parametrize("bad", ["99999999999999999999999", "9223372036854775808", "-99999999999999999999999"])
@pytest.mark.parametrize("field", [0, 1])
def test_uv_index_beyond_int64(tmp_path, bad, field):
    """Regression: a v or vt index too large for int64 raised OverflowError instead of a MeshError."""
    corner = f"{bad}/3" if field == 0 else f"3/{bad}"
    p = tmp_path / "uv.obj"
    p.write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 {corner}\n")
    with pytest.raises(IdpError, match=r"uv\.obj:7: .*(out of range|refers before)"):
        read_uv_obj(p)
