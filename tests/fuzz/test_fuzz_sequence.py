"""Fuzzing ``idp.mesh.sequence.open_sequence`` on ``.npz`` animation sequences (keys ``vertices`` (F, n, 3) and
``faces`` (m, 3)).

Property: opening the file and reading every frame (``check_all_frames``) either raises an
:class:`idp.errors.IdpError` or gives finite (n, 3) float64 frames and (m, 3) faces indexing them. ``np.load``
is never called with ``allow_pickle=True``: an object array holding a pickle that would create a file when
unpickled is refused, and the file never appears.
"""

from __future__ import annotations

import gc
import io
import pathlib
import tempfile
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fuzz.common import fuzz, mutated_bytes
from hypothesis import given
from hypothesis import strategies as st

from idp.errors import IdpError
from idp.mesh.sequence import check_all_frames, open_sequence

TETRA = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TETRA_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.fixture(autouse=True)
def _no_pickle(monkeypatch):
    """Fail any np.load call that would unpickle (the default is allow_pickle=False; it must stay so)."""
    real = np.load

    def guarded(*args: Any, **kwargs: Any) -> Any:
        assert not kwargs.get("allow_pickle", False), "np.load called with allow_pickle=True"
        return real(*args, **kwargs)

    monkeypatch.setattr(np, "load", guarded)


def _npy(array: Any, header: dict | None = None) -> bytes:
    """The .npy bytes of ``array``, or a raw header (any shape claim) followed by ``array``'s bytes."""
    buf = io.BytesIO()
    if header is None:
        np.lib.format.write_array(buf, np.asanyarray(array), allow_pickle=True)
    else:
        np.lib.format.write_array_header_1_0(buf, header)
        buf.write(np.ascontiguousarray(array).tobytes())
    return buf.getvalue()


def _npz(members: dict[str, bytes], compress: bool = False) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


def _frames(draw: st.DrawFn, F: int) -> np.ndarray:
    jitter = draw(st.floats(0, 0.05))
    return np.stack([TETRA * (1 + jitter * k) for k in range(F)])


DTYPES = [
    "<f8",
    ">f8",
    "<f4",
    "<f2",
    "<i8",
    "<u8",
    "<i4",
    "|b1",
    "<c16",
    "<U4",
    "|S4",
    "<M8[s]",
    "<m8[s]",
    "|V8",
    [("x", "<f8")],
]


def _cast(a: np.ndarray, dtype: Any) -> np.ndarray:
    try:
        return a.astype(dtype)
    except (TypeError, ValueError):
        return np.zeros(a.shape, dtype=dtype)


@st.composite
def npz_files(draw: st.DrawFn) -> bytes:
    """A valid two-key npz with one structural mutation (or none), sometimes also byte-mutated."""
    F = draw(st.integers(1, 3))
    vertices: Any = _frames(draw, F)
    faces: Any = TETRA_FACES.copy()
    extra: dict[str, bytes] = {}
    what = draw(
        st.sampled_from(
            [
                "none",
                "drop-key",
                "rename-key",
                "vertices-shape",
                "faces-shape",
                "vertices-dtype",
                "faces-dtype",
                "faces-range",
                "nonfinite",
                "empty",
                "object",
                "scalar",
                "extra-key",
                "header-shape",
                "fortran",
                "not-npy",
            ]
        )
    )
    if what == "drop-key":
        if draw(st.booleans()):
            vertices = None
        else:
            faces = None
    elif what == "rename-key":
        extra["Vertices.npy"] = _npy(vertices)
        vertices = None
    elif what == "vertices-shape":
        shape = tuple(draw(st.lists(st.integers(0, 5), min_size=0, max_size=4)))
        vertices = np.resize(vertices, shape) if shape else np.float64(1.0)
    elif what == "faces-shape":
        shape = tuple(draw(st.lists(st.integers(0, 5), min_size=0, max_size=3)))
        faces = np.resize(faces, shape) if shape else np.int64(1)
    elif what == "vertices-dtype":
        vertices = _cast(vertices, draw(st.sampled_from(DTYPES)))
    elif what == "faces-dtype":
        faces = _cast(faces, draw(st.sampled_from(DTYPES)))
    elif what == "faces-range":
        faces = faces.astype(np.int64)
        faces[draw(st.integers(0, 3)), draw(st.integers(0, 2))] = draw(
            st.sampled_from([-1, 4, 5, -(2**63), 2**63 - 1, 2**31])
        )
    elif what == "nonfinite":
        vertices[draw(st.integers(0, F - 1)), draw(st.integers(0, 3)), draw(st.integers(0, 2))] = draw(
            st.sampled_from([np.nan, np.inf, -np.inf])
        )
    elif what == "empty":
        if draw(st.booleans()):
            vertices = np.zeros((draw(st.integers(0, 2)), 0, 3))
        else:
            faces = np.zeros((0, 3), dtype=np.int64)
    elif what == "object":
        target = draw(st.sampled_from(["vertices", "faces"]))
        obj = np.empty(2, dtype=object)
        obj[0], obj[1] = [1.0, 2.0], "x"
        if target == "vertices":
            vertices = obj
        else:
            faces = obj
    elif what == "scalar":
        vertices = np.float64(draw(st.floats()))
    elif what == "extra-key":
        extra["other.npy"] = _npy(np.arange(3))
        extra["notes.txt"] = b"hello"
    elif what == "header-shape":
        # the header claims a shape (possibly huge) the data does not have
        shape = tuple(draw(st.lists(st.sampled_from([0, 1, 3, 4, 10**6, 10**12, 2**62]), min_size=1, max_size=3)))
        extra["vertices.npy"] = _npy(vertices, {"descr": "<f8", "fortran_order": False, "shape": shape})
        vertices = None
    elif what == "fortran":
        vertices = np.asfortranarray(vertices)
    elif what == "not-npy":
        extra["vertices.npy"] = draw(st.binary(max_size=64))
        vertices = None
    members = dict(extra)
    if vertices is not None:
        members["vertices.npy"] = _npy(vertices)
    if faces is not None:
        members["faces.npy"] = _npy(faces)
    data = _npz(members, compress=draw(st.booleans()))
    if draw(st.integers(0, 4)) == 0:
        data = draw(mutated_bytes(data, max_ops=2))
    return data


def _open(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "seq.npz"
        path.write_bytes(data)
        try:
            seq = open_sequence(path)
            check_all_frames(seq)
        except IdpError as exc:
            assert str(exc)
            return
        n = seq.num_vertices
        assert seq.num_frames >= 1 and n > 0
        assert seq.faces.dtype == np.int64 and seq.faces.ndim == 2 and seq.faces.shape[1] == 3
        assert seq.faces.shape[0] > 0 and seq.faces.min() >= 0 and seq.faces.max() < n
        for k in range(seq.num_frames):
            x = seq.frame(k)
            assert x.dtype == np.float64 and x.shape == (n, 3) and np.isfinite(x).all()


@fuzz(500)
@given(data=npz_files())
def test_npz_mutated(data):
    _open(data)


@fuzz(40)
@given(data=st.binary(max_size=512))
def test_npz_random_bytes(data):
    _open(data)


class _Touch:
    """Unpickling this object creates ``path`` (a stand-in for arbitrary code a pickle can run)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (pathlib.Path.touch, (self.path,))


@pytest.mark.parametrize("key", ["vertices", "faces"])
def test_pickle_in_npz_never_runs(tmp_path, key):
    marker = tmp_path / "pwned"
    payload = np.empty(1, dtype=object)
    payload[0] = _Touch(marker)
    arrays = {"vertices": TETRA[None], "faces": TETRA_FACES, key: payload}
    p = tmp_path / "seq.npz"
    p.write_bytes(_npz({f"{k}.npy": _npy(v) for k, v in arrays.items()}))
    with pytest.raises(IdpError, match="cannot read sequence file"):
        open_sequence(p)
    assert not marker.exists()


@pytest.mark.parametrize("raw", [b"", b"hello", b"PK\x03\x04"])
@pytest.mark.parametrize("key", ["vertices", "faces"])
def test_member_without_npy_magic(tmp_path, raw, key):
    """Regression: np.load returns a zip member without the .npy magic as bytes; that raised AttributeError."""
    members = {"vertices.npy": _npy(TETRA[None]), "faces.npy": _npy(TETRA_FACES), f"{key}.npy": raw}
    p = tmp_path / "seq.npz"
    p.write_bytes(_npz(members))
    with pytest.raises(IdpError, match=f"{key} is not a .npy array"):
        open_sequence(p)


@pytest.mark.parametrize("raw", [b"", b"PK\x03\x04 not a zip", b"\x93NUMPY garbage"])
def test_refused_file_is_closed(tmp_path, raw):
    """Regression: np.load(path) left its file handle open when the data was not an npz (a ResourceWarning)."""
    p = tmp_path / "seq.npz"
    p.write_bytes(raw)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            open_sequence(p)
        except IdpError:
            pass
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]
