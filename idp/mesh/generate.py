"""Procedural meshes idp makes itself: tet boxes and balls, closed test surfaces, 2D meshes.

Every generator returns positively oriented elements and closed, consistently outward
oriented surfaces (the tests check this), so scenes and tests do not need external files.

Grids are split with a mirrored Kuhn pattern: in each cube (square in 2D) the tets fan
around the diagonal that runs from the corner nearest the grid centre to the farthest one.
Neighbouring cells always agree on the diagonal of their shared face (it depends only on the
cells' common coordinates), so the mesh is conforming; and in every boundary cell each
tet contains the innermost corner, so after mapping a cube onto a ball no tet has all its
vertices on the sphere (no flat slivers).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import permutations
from typing import Any

import numpy as np
import numpy.typing as npt

from idp.errors import MeshError
from idp.mesh.surface import boundary_faces
from idp.mesh.types import SurfaceMesh, VolumeMesh


def _counts(resolution: int | Sequence[int], dim: int, name: str = "resolution") -> tuple[int, ...]:
    """Resolution as a dim-tuple of positive ints."""
    # typed Any: np.isscalar narrows to numpy's scalar union, which int() rejects; the checks below validate
    value: Any = resolution
    res: tuple[Any, ...] = (value,) * dim if np.isscalar(value) else tuple(value)
    if len(res) != dim or any(int(r) != r or int(r) < 1 for r in res):
        raise MeshError(f"{name} must be a positive int or {dim} positive ints, got {resolution!r}")
    return tuple(int(r) for r in res)


def _vec(x: float | Sequence[float], dim: int, name: str) -> np.ndarray:
    a = np.full(dim, float(np.asarray(x))) if np.isscalar(x) else np.asarray(x, dtype=np.float64)
    if a.shape != (dim,) or not np.all(np.isfinite(a)):
        raise MeshError(f"{name} must be {dim} finite numbers, got {x!r}")
    return a


def _fix_orientation(lattice: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Swap the first two indices of elements that are negative on the integer lattice."""
    x0 = lattice[elements[:, 0]]
    d = np.stack([lattice[elements[:, k]] - x0 for k in range(1, elements.shape[1])], axis=1)
    neg = np.linalg.det(d.astype(np.float64)) < 0
    swap = np.arange(elements.shape[1])
    swap[[0, 1]] = [1, 0]
    elements = elements.copy()
    elements[neg] = elements[neg][:, swap]
    return elements


def _simplex_grid(counts: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Integer lattice points (N, d) and positively oriented simplices of a mirrored Kuhn grid."""
    dim = len(counts)
    axes = [np.arange(c + 1) for c in counts]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    strides = np.cumprod([1] + [c + 1 for c in counts[::-1]])[:-1][::-1]  # vertex id strides

    cells = np.stack(np.meshgrid(*[np.arange(c) for c in counts], indexing="ij"), axis=-1).reshape(-1, dim)
    # Start corner per axis: 1 (the high side) for cells in the lower half, else 0.
    half = np.array(counts) / 2.0
    start = (cells + 0.5 < half).astype(np.int64)

    tets = []
    for perm in permutations(range(dim)):  # d! simplices per cell (6 in 3D, 2 in 2D)
        corner = start.copy()
        path = [corner.copy()]
        for axis in perm:
            corner[:, axis] = 1 - corner[:, axis]
            path.append(corner.copy())
        ids = np.stack([((cells + c) * strides).sum(axis=1) for c in path], axis=1)
        tets.append(ids)
    elements = np.stack(tets, axis=1).reshape(-1, dim + 1).astype(np.int64)
    return lattice, _fix_orientation(lattice, elements)


def _box_simplex_mesh(lo, hi, resolution, dim: int, name: str) -> VolumeMesh:
    """Structured simplex mesh (tets in 3D, triangles in 2D) of the axis-aligned box [lo, hi]."""
    lo_a, hi_a = _vec(lo, dim, "lo"), _vec(hi, dim, "hi")
    if np.any(hi_a <= lo_a):
        raise MeshError(f"{name} needs hi > lo on every axis, got lo={lo!r} hi={hi!r}")
    counts = _counts(resolution, dim)
    lattice, elements = _simplex_grid(counts)
    verts = lo_a + lattice / np.array(counts) * (hi_a - lo_a)
    return VolumeMesh(verts, elements, source=name)


def tet_box(
    lo: Sequence[float] = (-1.0, -1.0, -1.0),
    hi: Sequence[float] = (1.0, 1.0, 1.0),
    resolution: int | Sequence[int] = (4, 4, 4),
) -> VolumeMesh:
    """Structured tet mesh of the box [lo, hi]: resolution cells per axis, 6 tets per cell."""
    return _box_simplex_mesh(lo, hi, resolution, 3, "tet_box")


def _cube_to_ball(p: np.ndarray) -> np.ndarray:
    """Map [-1,1]^d onto the unit ball, keeping each concentric cube shell on a sphere.

    A point p with r = max|p_i| is sent to r * s(p / r), where s is the smooth cube-surface
    -> sphere map x_i' = x_i * sqrt(1 - sum_{j!=i} x_j^2 / 2 + prod_{j!=i} x_j^2 / 3)
    (2D: x' = x sqrt(1 - y^2/2)). Being homogeneous of degree 1, the map distorts cells by
    a bounded amount at every resolution; a smooth map cannot flatten the cube's corners
    without a singular Jacobian there, which produced slivers that worsened with resolution.
    """
    r = np.abs(p).max(axis=1)
    safe = np.where(r > 0, r, 1.0)
    u = p / safe[:, None]
    sq = u * u
    if p.shape[1] == 2:
        x, y = sq[:, 0], sq[:, 1]
        f = np.stack([1 - y / 2, 1 - x / 2], axis=1)
    else:
        x, y, z = sq[:, 0], sq[:, 1], sq[:, 2]
        f = np.stack(
            [1 - y / 2 - z / 2 + y * z / 3, 1 - z / 2 - x / 2 + z * x / 3, 1 - x / 2 - y / 2 + x * y / 3],
            axis=1,
        )
    d = u * np.sqrt(f)
    norm = np.linalg.norm(d, axis=1)
    d /= np.where(norm > 0, norm, 1.0)[:, None]  # unit up to rounding already; make it exact
    return np.where((r > 0)[:, None], d * r[:, None], 0.0)


def tet_ellipsoid(
    radii: Sequence[float] = (1.0, 1.0, 1.0),
    center: Sequence[float] = (0.0, 0.0, 0.0),
    resolution: int = 6,
) -> VolumeMesh:
    """Tet mesh of an ellipsoid: a (2*resolution)^3 grid of [-1,1]^3 mapped onto the ball.

    ``resolution`` is the number of grid cells per radius. Boundary vertices lie exactly on
    the ellipsoid.
    """
    r = _vec(radii, 3, "radii")
    if np.any(r <= 0):
        raise MeshError(f"radii must be positive, got {radii!r}")
    n = _counts(resolution, 1)[0]
    lattice, elements = _simplex_grid((2 * n,) * 3)
    ball = _cube_to_ball(lattice / n - 1.0)
    return VolumeMesh(ball * r + _vec(center, 3, "center"), elements, source="tet_ellipsoid")


def tet_ball(radius: float = 1.0, center: Sequence[float] = (0.0, 0.0, 0.0), resolution: int = 6) -> VolumeMesh:
    """Tet mesh of a ball (see :func:`tet_ellipsoid`)."""
    mesh = tet_ellipsoid((radius,) * 3, center, resolution)
    mesh.source = "tet_ball"
    return mesh


def box_surface(
    lo: Sequence[float] = (-1.0, -1.0, -1.0),
    hi: Sequence[float] = (1.0, 1.0, 1.0),
    resolution: int | Sequence[int] = 4,
) -> SurfaceMesh:
    """Closed outward triangle surface of a box, each side a resolution x resolution grid."""
    vol = tet_box(lo, hi, _counts(resolution, 3))
    faces = boundary_faces(vol.elements)
    used = np.unique(faces)
    remap = np.full(vol.num_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return SurfaceMesh(vol.vertices[used], remap[faces], source="box_surface")


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit icosahedron: 12 vertices, 20 outward faces."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=float,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
         [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def _subdivide_on_sphere(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 1→4 split of every face, new (edge-midpoint) vertices pushed onto the unit sphere."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    mid = v[uniq].mean(axis=1)
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    m = inv.reshape(3, -1) + v.shape[0]  # midpoint ids of edges (01), (12), (20) per face
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = m
    faces = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return np.vstack([v, mid]), faces


def ellipsoid_surface(
    radii: Sequence[float] = (0.5, 0.5, 0.5),
    center: Sequence[float] = (0.0, 0.0, 0.0),
    subdivisions: int = 4,
    noise: float = 0.0,
    smoothing: int = 0,
    seed: int = 0,
) -> SurfaceMesh:
    """Closed outward ellipsoid surface from a subdivided icosahedron (20·4^s faces, nearly uniform).

    ``noise`` > 0 moves every vertex radially by a uniform random fraction in [−noise, noise] of its radius
    (``numpy.random.default_rng(seed)``: the same seed gives the same surface), averaged over ``smoothing``
    rounds of neighbours first (lower-frequency bumps); with a positive normal flow such a surface creases into
    brain-like folds (paper Fig. 12c)."""
    if not (0.0 <= noise < 0.5):
        raise ValueError(f"noise must be in [0, 0.5) (a fraction of the radius), got {noise}")
    if subdivisions < 0 or subdivisions > 7:
        raise ValueError(f"subdivisions must be in [0, 7], got {subdivisions}")
    v, f = _icosahedron()
    for _ in range(int(subdivisions)):
        v, f = _subdivide_on_sphere(v, f)
    if noise > 0:
        r = np.asarray(np.random.default_rng(seed).uniform(-noise, noise, v.shape[0]), dtype=float)
        if smoothing:
            e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
            deg = np.bincount(e[:, 0], minlength=v.shape[0]).astype(float)
            for _ in range(int(smoothing)):
                r = 0.5 * r + 0.5 * np.bincount(e[:, 0], weights=r[e[:, 1]], minlength=v.shape[0]) / deg
            r *= noise / max(float(np.abs(r).max()), 1e-300)
        v = v * (1.0 + r)[:, None]
    out = v * _vec(radii, 3, "radii")[None, :] + _vec(center, 3, "center")[None, :]
    return SurfaceMesh(out, f, source=f"ellipsoid_surface(noise={noise}, seed={seed})")


def revolve_profile(ys: npt.ArrayLike, rs: npt.ArrayLike, segments: int) -> SurfaceMesh:
    """Surface of revolution about the y axis of the profile (r(t), y(t)).

    Faces are outward oriented when the profile runs from bottom to top. An end with ``r == 0``
    becomes a single pole vertex (both ends zero gives a closed surface), an end with ``r > 0`` is left open. Interior
    profile radii must be positive. Ring vertex j sits at angle 2*pi*j/segments.
    """
    y = np.asarray(ys, dtype=np.float64)
    r = np.asarray(rs, dtype=np.float64)
    if y.ndim != 1 or y.shape != r.shape or y.size < 2:
        raise MeshError("revolve_profile needs two 1D sequences of equal length >= 2")
    if np.any(r[1:-1] <= 0) or np.any(r < 0):
        raise MeshError("revolve_profile: radii must be >= 0, and > 0 away from the ends")
    segments = _counts(segments, 1, "segments")[0]
    if segments < 3:
        raise MeshError(f"segments must be >= 3, got {segments}")
    p = y.size
    theta = 2.0 * np.pi * np.arange(segments) / segments
    pole = r == 0.0
    sizes = np.where(pole, 1, segments)
    base = np.concatenate([[0], np.cumsum(sizes)[:-1]])

    blocks: list[npt.ArrayLike] = []
    for i in range(p):  # loop over profile points (rings), not over faces
        if pole[i]:
            blocks.append([[0.0, y[i], 0.0]])
        else:
            ring = [r[i] * np.cos(theta), np.full(segments, y[i]), r[i] * np.sin(theta)]
            blocks.append(np.stack(ring, axis=1))
    verts = np.concatenate([np.asarray(b, dtype=np.float64) for b in blocks], axis=0)

    j = np.arange(segments)
    jn = (j + 1) % segments
    faces = []
    for i in range(p - 1):
        lo_ring = base[i] + (0 if pole[i] else j)
        lo_next = base[i] + (0 if pole[i] else jn)
        hi_ring = base[i + 1] + (0 if pole[i + 1] else j)
        hi_next = base[i + 1] + (0 if pole[i + 1] else jn)
        if pole[i] and pole[i + 1]:
            raise MeshError("revolve_profile: two consecutive zero radii")
        # Quad (a=lo_ring, b=hi_ring, c=hi_next, d=lo_next) -> (a,b,c), (a,c,d); normal
        # d/dt x d/dtheta points outward for this parameterisation.
        if not pole[i + 1]:
            faces.append(np.stack(np.broadcast_arrays(lo_ring, hi_ring, hi_next), axis=1))
        if not pole[i]:
            faces.append(np.stack(np.broadcast_arrays(lo_ring, hi_next, lo_next), axis=1))
    return SurfaceMesh(verts, np.concatenate(faces).astype(np.int64), source="revolve_profile")


def cylinder_surface(
    radius: float = 0.5,
    y0: float = -0.5,
    y1: float = 0.5,
    segments: int = 32,
    rings: int = 8,
    cap_rings: int = 3,
) -> SurfaceMesh:
    """Closed cylinder along y from y0 to y1: ``rings`` bands on the side, flat capped ends
    made of ``cap_rings`` annuli around a centre vertex."""
    if radius <= 0 or y1 <= y0:
        raise MeshError(f"cylinder needs radius > 0 and y1 > y0, got {radius}, {y0}, {y1}")
    rings = _counts(rings, 1, "rings")[0]
    cap_rings = _counts(cap_rings, 1, "cap_rings")[0]
    cap = radius * np.arange(cap_rings + 1) / cap_rings  # 0 .. radius
    side = y0 + (y1 - y0) * np.arange(1, rings) / rings
    ys = np.concatenate([np.full(cap_rings + 1, y0), side, np.full(cap_rings + 1, y1)])
    rs = np.concatenate([cap, np.full(rings - 1, radius), cap[::-1]])
    mesh = revolve_profile(ys, rs, segments)
    mesh.source = "cylinder_surface"
    return mesh


def _resample(y: np.ndarray, r: np.ndarray, intervals: int) -> tuple[np.ndarray, np.ndarray]:
    """intervals + 1 points evenly spaced in arc length along the dense polyline (y, r)."""
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(y), np.diff(r)))])
    t = np.linspace(0.0, arc[-1], intervals + 1)
    return np.interp(t, arc, y), np.interp(t, arc, r)


def hourglass_profile(
    bulb_radius: float = 0.5,
    neck_radius: float = 0.15,
    lower_center: float = 0.0,
    upper_center: float = 1.6,
    samples: int = 49,
) -> tuple[np.ndarray, np.ndarray]:
    """(ys, rs) of the hourglass profile from the lower pole to the upper pole.

    Profile, bottom to top (R = bulb_radius, m = midpoint of the centres):
    lower pole -> quarter circle of radius R about y=lower_center up to its equator (r=R);
    then r(y) = neck + (R - neck) * (1 + cos(pi*s)) / 2 with s going 0 -> 1 from the lower
    centre to m (the neck, r = neck_radius); then the mirror image up to the upper pole.
    Slopes match (zero) at every joint, so the profile is C1 (curvature jumps at the
    equators). Each of the four pieces is sampled evenly in arc length with a share of the
    ``samples - 1`` intervals proportional to its length, so the poles and both equators
    (hence the bounding box) are exact, and the neck point is exact when that share is even.
    """
    R, rn = float(bulb_radius), float(neck_radius)
    lc, uc = float(lower_center), float(upper_center)
    if not (0 < rn < R):
        raise MeshError(f"hourglass needs 0 < neck_radius < bulb_radius, got {rn}, {R}")
    if uc <= lc:
        raise MeshError(f"hourglass needs upper_center > lower_center, got {uc}, {lc}")
    intervals = int(samples) - 1
    if intervals < 4:
        raise MeshError(f"hourglass profile needs at least 5 samples, got {samples}")
    dense = 4001
    phi = np.linspace(0.0, np.pi / 2, dense)
    cap_y, cap_r = lc - R * np.cos(phi), R * np.sin(phi)
    mid = 0.5 * (lc + uc)
    s = np.linspace(0.0, 1.0, dense)
    neck_y = lc + s * (mid - lc)
    neck_r = rn + (R - rn) * (1.0 + np.cos(np.pi * s)) / 2.0
    cap_len = R * np.pi / 2
    neck_len = float(np.sum(np.hypot(np.diff(neck_y), np.diff(neck_r))))
    n_cap = min(max(1, round(intervals * cap_len / (2 * cap_len + 2 * neck_len))), (intervals - 2) // 2)
    n_neck = intervals - 2 * n_cap
    n_low, n_up = (n_neck + 1) // 2, n_neck // 2
    y1, r1 = _resample(cap_y, cap_r, n_cap)
    y2, r2 = _resample(neck_y, neck_r, n_low)
    y3, r3 = _resample(neck_y, neck_r, n_up)
    ys = np.concatenate([y1, y2[1:], (lc + uc) - y3[-2::-1], (lc + uc) - y1[-2::-1]])
    rs = np.concatenate([r1, r2[1:], r3[-2::-1], r1[-2::-1]])
    rs[0] = rs[-1] = 0.0
    ys[0], ys[-1] = lc - R, uc + R
    return ys, rs


def hourglass_surface(
    bulb_radius: float = 0.5,
    neck_radius: float = 0.15,
    lower_center: float = 0.0,
    upper_center: float = 1.6,
    segments: int = 32,
    rings: int = 48,
) -> SurfaceMesh:
    """Closed hourglass about the y axis: two bulbs joined by a neck (see :func:`hourglass_profile`).

    ``rings`` is the number of profile intervals from pole to pole.
    """
    rings = _counts(rings, 1, "rings")[0]
    if rings < 4:
        raise MeshError(f"hourglass needs rings >= 4, got {rings}")
    ys, rs = hourglass_profile(bulb_radius, neck_radius, lower_center, upper_center, rings + 1)
    mesh = revolve_profile(ys, rs, segments)
    mesh.source = "hourglass_surface"
    return mesh


def tri_rectangle(
    lo: Sequence[float] = (0.0, 0.0),
    hi: Sequence[float] = (1.0, 1.0),
    resolution: int | Sequence[int] = (4, 4),
) -> VolumeMesh:
    """2D triangle mesh (counter-clockwise) of a rectangle, 2 triangles per grid square."""
    return _box_simplex_mesh(lo, hi, resolution, 2, "tri_rectangle")


def tri_disk(radius: float = 1.0, center: Sequence[float] = (0.0, 0.0), resolution: int = 6) -> VolumeMesh:
    """2D triangle mesh of a disk: a (2*resolution)^2 grid of [-1,1]^2 mapped onto the disk."""
    if radius <= 0:
        raise MeshError(f"radius must be positive, got {radius}")
    n = _counts(resolution, 1)[0]
    lattice, elements = _simplex_grid((2 * n, 2 * n))
    disk = _cube_to_ball(lattice / n - 1.0)
    return VolumeMesh(disk * radius + _vec(center, 2, "center"), elements, source="tri_disk")


def polygon_circle(radius: float, center: Sequence[float] = (0.0, 0.0), segments: int = 64) -> SurfaceMesh:
    """Closed counter-clockwise polyline (outward normals) approximating a circle."""
    if radius <= 0:
        raise MeshError(f"radius must be positive, got {radius}")
    segments = _counts(segments, 1, "segments")[0]
    if segments < 3:
        raise MeshError(f"segments must be >= 3, got {segments}")
    t = 2.0 * np.pi * np.arange(segments) / segments
    verts = radius * np.stack([np.cos(t), np.sin(t)], axis=1) + _vec(center, 2, "center")
    i = np.arange(segments)
    return SurfaceMesh(verts, np.stack([i, (i + 1) % segments], axis=1), source="polygon_circle")


def polygon_box(lo: Sequence[float], hi: Sequence[float], resolution: int | Sequence[int] = 4) -> SurfaceMesh:
    """Closed counter-clockwise polyline around the rectangle [lo, hi], resolution segments per side."""
    lo_a, hi_a = _vec(lo, 2, "lo"), _vec(hi, 2, "hi")
    if np.any(hi_a <= lo_a):
        raise MeshError(f"polygon_box needs hi > lo, got lo={lo!r} hi={hi!r}")
    nx, ny = _counts(resolution, 2)
    tx = np.arange(nx) / nx
    ty = np.arange(ny) / ny
    x0, y0 = lo_a
    x1, y1 = hi_a
    bottom = np.stack([x0 + tx * (x1 - x0), np.full(nx, y0)], axis=1)
    right = np.stack([np.full(ny, x1), y0 + ty * (y1 - y0)], axis=1)
    top = np.stack([x1 - tx * (x1 - x0), np.full(nx, y1)], axis=1)
    left = np.stack([np.full(ny, x0), y1 - ty * (y1 - y0)], axis=1)
    verts = np.concatenate([bottom, right, top, left])
    i = np.arange(verts.shape[0])
    return SurfaceMesh(verts, np.stack([i, (i + 1) % i.size], axis=1), source="polygon_box")
