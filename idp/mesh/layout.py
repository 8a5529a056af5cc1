"""Layouts for instancing: the transforms of N copies of an object (grid, ring, seeded random).

Every generator returns ``(linear, translate)``: ``linear`` is (N, d, d) (a rotation times a scale, or a
rotation alone) and ``translate`` is (N, d); copy ``k`` of a point ``x`` is ``linear[k] @ x + translate[k]``.
``d`` is 2 or 3. In 2D a rotation is in the plane (counter-clockwise by the angle; no axis).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from idp.errors import MeshError
from idp.mesh.placement import rotation_matrix, rotation_matrix_2d

Transforms = tuple[np.ndarray, np.ndarray]


def _rotation(d: int, degrees: float, axis: Sequence[float] | np.ndarray | None) -> np.ndarray:
    if d == 2:
        if axis is not None:
            raise MeshError("a 2D rotation has no axis (it is in the plane)")
        return rotation_matrix_2d(degrees)
    if axis is None:
        raise MeshError("a 3D rotation needs an axis")
    return rotation_matrix(tuple(float(a) for a in axis), degrees)


def grid_transforms(
    counts: Sequence[int], spacing: Sequence[float], origin: Sequence[float] | None = None
) -> Transforms:
    """Copies on a regular grid: ``counts[a]`` copies along axis ``a``, ``spacing[a]`` apart, copy 0 moved by
    ``origin``. Copies are numbered with x fastest, then y, then z: ``k = i + nx * (j + ny * l)``."""
    d = len(counts)
    if d not in (2, 3) or len(spacing) != d or (origin is not None and len(origin) != d):
        raise MeshError(f"grid: counts, spacing and origin need 2 or 3 entries each (got {counts}, {spacing})")
    if any(int(c) < 1 for c in counts):
        raise MeshError(f"grid: counts must be >= 1 (got {list(counts)})")
    o = np.zeros(d) if origin is None else np.asarray(origin, dtype=np.float64)
    # meshgrid with indexing='ij' over the axes reversed makes x the fastest-varying index
    idx = np.stack(np.meshgrid(*[np.arange(int(c)) for c in reversed(counts)], indexing="ij"), axis=-1)
    idx = idx.reshape(-1, d)[:, ::-1]
    translate = o + idx * np.asarray(spacing, dtype=np.float64)
    linear = np.broadcast_to(np.eye(d), (translate.shape[0], d, d)).copy()
    return linear, translate


def ring_basis(axis: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, u, v)``: the unit axis, the ring's angle-0 direction ``u`` and ``v = a × u`` (so ``u × v = a``).

    ``u`` is the coordinate axis least aligned with ``a`` (x on ties before y before z), made perpendicular
    to ``a``: x for an axis along ±y or ±z, y for an axis along ±x."""
    a = np.asarray(axis, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if a.shape != (3,) or not np.isfinite(n) or n == 0.0:
        raise MeshError(f"ring axis must be 3 finite numbers, not all zero (got {list(axis)})")
    a = a / n
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = e - (e @ a) * a
    u /= np.linalg.norm(u)
    return a, u, np.cross(a, u)


def ring_transforms(
    count: int,
    radius: float,
    center: Sequence[float],
    axis: Sequence[float] | None = None,
    start_degrees: float = 0.0,
    face_center: bool = True,
    rotate_offset_degrees: float = 0.0,
) -> Transforms:
    """Copies on a circle: copy ``k`` at angle ``phi_k = start_degrees + k * 360 / count``.

    3D: translated to ``center + radius * (cos(phi) u + sin(phi) v)`` with ``(u, v)`` from :func:`ring_basis`
    (right-handed about ``axis``), and rotated about ``axis`` by ``rotate_offset_degrees + phi`` when
    ``face_center`` (so each copy turns with the ring and keeps its orientation relative to the centre: the
    copy at ``phi`` is the copy at 0 turned by ``phi`` about the ring's axis through ``center``) or by
    ``rotate_offset_degrees`` alone otherwise. 2D: ``center + radius * (cos(phi), sin(phi))``, rotated
    counter-clockwise in the plane by the same angle; ``axis`` must be None.
    """
    d = len(center)
    if count < 1:
        raise MeshError(f"ring: count must be >= 1 (got {count})")
    c = np.asarray(center, dtype=np.float64)
    phi = start_degrees + np.arange(count) * (360.0 / count)
    rad = np.radians(phi)
    if d == 2:
        if axis is not None:
            raise MeshError("ring: a 2D ring has no axis (it is in the plane)")
        a = None
        dirs = np.stack([np.cos(rad), np.sin(rad)], axis=1)
    elif d == 3:
        a, u, v = ring_basis((0.0, 1.0, 0.0) if axis is None else axis)
        dirs = np.cos(rad)[:, None] * u + np.sin(rad)[:, None] * v
    else:
        raise MeshError(f"ring: center must have 2 or 3 entries (got {d})")
    translate = c + radius * dirs
    angles = rotate_offset_degrees + (phi if face_center else np.zeros(count))
    linear = np.stack([_rotation(d, float(t), a) for t in angles])
    return linear, translate


def _random_axis(rng: np.random.Generator) -> np.ndarray:
    while True:  # a normal sample normalised is uniform on the sphere; a (near) zero sample is drawn again
        a = rng.normal(size=3)
        n = float(np.linalg.norm(a))
        if n > 1e-12:
            return a / n


def random_transforms(
    count: int,
    seed: int,
    translate_lo: Sequence[float],
    translate_hi: Sequence[float],
    rotate_axis: Sequence[float] | None = None,
    degrees_lo: float = 0.0,
    degrees_hi: float = 360.0,
    scale_lo: float = 1.0,
    scale_hi: float = 1.0,
) -> Transforms:
    """Seeded random copies: ``numpy.random.default_rng(seed)`` draws, for copy 0, 1, ... in turn, a
    translation uniform in the box ``[translate_lo, translate_hi]``, in 3D an axis uniform on the sphere
    (unless ``rotate_axis`` is given), an angle uniform in ``[degrees_lo, degrees_hi]`` and a uniform scale
    factor in ``[scale_lo, scale_hi]``; copy ``k`` is ``R_k (s_k x) + t_k``.

    The same arguments give the same transforms bit for bit, and copy ``k`` does not depend on ``count``
    (a longer layout extends a shorter one). In 2D, ``rotate_axis`` must be None (rotation in the plane).
    """
    lo = np.asarray(translate_lo, dtype=np.float64)
    hi = np.asarray(translate_hi, dtype=np.float64)
    d = lo.shape[0]
    if d not in (2, 3) or hi.shape != (d,):
        raise MeshError(f"random: translate_lo and translate_hi need 2 or 3 entries each (got {lo}, {hi})")
    if count < 1:
        raise MeshError(f"random: count must be >= 1 (got {count})")
    if d == 2 and rotate_axis is not None:
        raise MeshError("random: a 2D layout has no rotate_axis (rotation is in the plane)")
    fixed_axis = None if rotate_axis is None or d == 2 else np.asarray(rotate_axis, dtype=np.float64)
    rng = np.random.default_rng(seed)
    linear = np.empty((count, d, d))
    translate = np.empty((count, d))
    for k in range(count):
        translate[k] = rng.uniform(lo, hi)
        axis = None if d == 2 else (_random_axis(rng) if fixed_axis is None else fixed_axis)
        deg = float(rng.uniform(degrees_lo, degrees_hi))
        s = float(rng.uniform(scale_lo, scale_hi))
        linear[k] = _rotation(d, deg, axis) * s
    return linear, translate


def explicit_transform(
    d: int,
    scale: float | Sequence[float] = 1.0,
    rotations: Sequence[tuple[Sequence[float] | None, float]] = (),
    translate: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One copy's ``(linear (d, d), translate (d,))`` from a scale (a number or one per axis), rotations
    ``(axis or None, degrees)`` applied in order about the origin, and a translation: ``R_k ... R_1 S x + t``."""
    s = np.asarray(scale, dtype=np.float64)
    lin = np.diag(np.full(d, float(s)) if s.ndim == 0 else s)
    for axis, deg in rotations:
        lin = _rotation(d, deg, axis) @ lin
    t = np.zeros(d) if translate is None else np.asarray(translate, dtype=np.float64)
    return lin, t
