"""Placing meshes in a scene (scale, rotate, translate) and selecting vertices by box.

Scenes describe where each object goes with a scale, an ordered list of rotations and a
translation; handles are picked as the vertices inside a box, optionally given as fractions
of the object's bounding box so a scene does not depend on the mesh's units.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from idp.errors import MeshError

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _axis_vector(axis: str | Sequence[float]) -> np.ndarray:
    if isinstance(axis, str):
        key = axis.strip().lower()
        if key not in _AXES:
            raise MeshError(f"unknown rotation axis {axis!r}; use 'x', 'y', 'z' or a 3-vector")
        return np.array(_AXES[key])
    a = np.asarray(axis, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise MeshError(f"rotation axis must be 'x', 'y', 'z' or 3 finite numbers, got {axis!r}")
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise MeshError("rotation axis must be non-zero")
    return a / n


def rotation_matrix(axis: str | Sequence[float], degrees: float) -> np.ndarray:
    """Right-handed rotation by ``degrees`` about ``axis`` (normalised), as a (3, 3) matrix."""
    k = _axis_vector(axis)
    t = np.radians(float(degrees))
    c, s = np.cos(t), np.sin(t)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return c * np.eye(3) + s * kx + (1.0 - c) * np.outer(k, k)


def rotation_matrix_2d(degrees: float) -> np.ndarray:
    """Counter-clockwise 2D rotation by ``degrees``, as a (2, 2) matrix."""
    t = np.radians(float(degrees))
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s], [s, c]])


def _rotation_2d(item) -> np.ndarray:
    """A 2D rotation item is a number of degrees, or ('z' or (0, 0, 1), degrees)."""
    if np.isscalar(item):
        return rotation_matrix_2d(float(np.asarray(item)))
    if len(item) == 2:
        axis, deg = item
        ok = (isinstance(axis, str) and axis.lower() == "z") or (
            not isinstance(axis, str) and np.allclose(_axis_vector(axis), (0, 0, 1))
        )
        if ok:
            return rotation_matrix_2d(float(deg))
    raise MeshError(f"2D rotations are given in degrees (about z), got {item!r}")


def place(
    vertices: np.ndarray,
    scale: float | Sequence[float] = 1.0,
    rotations: Sequence = (),
    translation: Sequence[float] | None = None,
) -> np.ndarray:
    """Return ``R_k ... R_1 (scale * x) + translation`` for every vertex (a new array).

    ``scale`` is a float or one factor per axis; ``rotations`` are ``(axis, degrees)`` pairs
    in 3D or plain degrees in 2D, applied in order about the origin.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise MeshError(f"vertices must be (n, 2) or (n, 3), got shape {v.shape}")
    d = v.shape[1]
    s = np.asarray(scale, dtype=np.float64)
    if s.ndim == 0:
        s = np.full(d, float(s))
    if s.shape != (d,) or not np.all(np.isfinite(s)) or np.any(s == 0):
        raise MeshError(f"scale must be a non-zero number or {d} non-zero numbers, got {scale!r}")
    rot = np.eye(d)
    for item in rotations:
        if d == 2:
            r = _rotation_2d(item)
        else:
            try:
                axis, deg = item
            except (TypeError, ValueError):
                raise MeshError(f"3D rotations are (axis, degrees) pairs, got {item!r}") from None
            r = rotation_matrix(axis, deg)
        rot = r @ rot
    out = (v * s) @ rot.T
    if translation is not None:
        t = np.asarray(translation, dtype=np.float64)
        if t.shape != (d,) or not np.all(np.isfinite(t)):
            raise MeshError(f"translation must be {d} finite numbers, got {translation!r}")
        out = out + t
    return out


def select_in_box(
    vertices: np.ndarray,
    lo: npt.ArrayLike,
    hi: npt.ArrayLike,
    relative_to: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> np.ndarray:
    """Indices (int64) of vertices inside the closed box [lo, hi].

    With ``relative_to=(bbox_min, bbox_max)``, ``lo``/``hi`` are fractions of that box per
    axis (0 = min, 1 = max) and are converted to absolute coordinates first.
    """
    v = np.asarray(vertices, dtype=np.float64)
    d = v.shape[1]
    lo_a = np.asarray(lo, dtype=np.float64)
    hi_a = np.asarray(hi, dtype=np.float64)
    if lo_a.shape != (d,) or hi_a.shape != (d,):
        raise MeshError(f"selection box corners must have {d} coordinates, got {lo!r}, {hi!r}")
    if relative_to is not None:
        bmin = np.asarray(relative_to[0], dtype=np.float64)
        bmax = np.asarray(relative_to[1], dtype=np.float64)
        if bmin.shape != (d,) or bmax.shape != (d,):
            raise MeshError(f"relative_to must be two points with {d} coordinates")
        # (1-f)*min + f*max hits min and max exactly at f = 0 and f = 1.
        lo_a = (1.0 - lo_a) * bmin + lo_a * bmax
        hi_a = (1.0 - hi_a) * bmin + hi_a * bmax
    inside = np.all((v >= lo_a) & (v <= hi_a), axis=1)
    return np.flatnonzero(inside).astype(np.int64)
