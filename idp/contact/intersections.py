"""Exact-enough detection of intersecting surface primitives (the input check and every frame's 3D certificate).

IPC needs an intersection-free start state: a surface edge that crosses a surface triangle
(3D) or two boundary segments that cross (2D) make the barrier undefined. Detection runs in
three stages: a broad phase (a uniform grid over the bounding boxes in 3D, a k-d tree in 2D),
a float64 orientation filter that rejects the pairs it can prove disjoint (compiled in 3D,
vectorised in 2D), and ipctk's robust predicates as the final word on every pair the filter
could not reject. Pairs of primitives that share a vertex are never reported (they touch by
construction).

The 3D broad phase is its own code, not the solver's contact grid (``idp.contact._broad_phase``), so the
certificate does not lean on what it checks. It replaced ipctk's LBVH here because that hands its candidates back
as one Python object each: on the Fig. 12 cat's last frame (63 K candidates) building them and reading their ids
took 80 of the function's 170 ms. Grid, gathering and float filter are one compiled pass
(:func:`_undecided_edge_face_pairs`), so every frame's certificate uses it too (:func:`has_intersections`: 2.0 ms
against ipctk's ``has_intersections`` 3.9–5.2 ms on a late bunny_700 frame; docs/benchmarks.md).
"""

from __future__ import annotations

import collections
import hashlib
import math

import numpy as np
from numba import njit

from idp._leaf import leaf_njit
from idp.errors import MeshError

# Relative slack on the float64 orientation determinants: anything within it is "unsure"
# and goes to ipctk's robust predicates instead of being decided here.
_SLACK = 1e-12


def _check(vertices: np.ndarray, cells: np.ndarray, dim: int, width: int, name: str):
    v = np.asarray(vertices, dtype=np.float64)
    c = np.asarray(cells)
    if v.ndim != 2 or v.shape[1] != dim:
        raise MeshError(f"vertices must be (n, {dim}), got shape {v.shape}")
    if c.ndim != 2 or c.shape[1] != width:
        raise MeshError(f"{name} must be (m, {width}) indices, got shape {c.shape}")
    c = c.astype(np.int64, copy=False)
    if c.size and (c.min() < 0 or c.max() >= v.shape[0]):
        raise MeshError(f"{name} reference vertices outside [0, {v.shape[0]})")
    if not np.all(np.isfinite(v)):
        raise MeshError("vertices contain NaN or infinite coordinates")
    return np.ascontiguousarray(v), c


def _sign2(a, b, c, scale: float) -> np.ndarray:
    """Sign of orient2d(a, b, c) = det[b-a, c-a] per row; 0 where unsure."""
    u, v = b - a, c - a
    det = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
    bound = _SLACK * (nu * nv + scale * (nu + nv))
    return np.where(det > bound, 1, np.where(det < -bound, -1, 0))


def _same(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """True where both signs are sure and equal (both points strictly on one side)."""
    return (s1 * s2) == 1


@njit(cache=True)
def _grid(v, e, f):  # pragma: no cover - compiled
    """(origin, cell size h, dims, lo, hi) of the uniform grid for the edge/face boxes: cells about twice the median
    edge box, at most four cells per box, coarser while the cell lists would hold more than 32 entries per box (boxes
    far larger than most, like the long spokes of a fan, are listed under many cells); ``lo``, ``hi`` (ne + nf, 3):
    the boxes themselves, the edges' first, for :func:`_undecided_edge_face_pairs`."""
    ne, nf = e.shape[0], f.shape[0]
    lo = np.empty((ne + nf, 3))
    hi = np.empty((ne + nf, 3))
    side = np.empty(ne)
    for i in range(ne):
        s = 0.0
        for ax in range(3):
            a, b = v[e[i, 0], ax], v[e[i, 1], ax]
            lo[i, ax], hi[i, ax] = min(a, b), max(a, b)
            s = max(s, hi[i, ax] - lo[i, ax])
        side[i] = s
    for j in range(nf):
        for ax in range(3):
            a, b, c = v[f[j, 0], ax], v[f[j, 1], ax], v[f[j, 2], ax]
            lo[ne + j, ax], hi[ne + j, ax] = min(a, min(b, c)), max(a, max(b, c))
    origin = np.empty(3)
    extent = np.empty(3)
    for ax in range(3):
        origin[ax] = lo[:, ax].min()
        extent[ax] = hi[:, ax].max() - origin[ax]
    h = 2.0 * np.median(side)
    if not h > 0.0:  # (nearly) every edge a point: one cell per axis
        h = max(extent.max(), 1.0)
    cells = 1.0
    for ax in range(3):
        cells *= math.floor(extent[ax] / h) + 1.0
    if cells > 4.0 * (ne + nf):
        h *= (cells / (4.0 * (ne + nf))) ** (1.0 / 3.0)
    dims = np.empty(3, np.int64)
    while True:
        for ax in range(3):
            dims[ax] = np.int64(math.floor(extent[ax] / h)) + 1
        listed = 0
        for k in range(ne + nf):
            n = 1
            for ax in range(3):
                n *= _cell(hi[k, ax], origin[ax], h, dims[ax]) - _cell(lo[k, ax], origin[ax], h, dims[ax]) + 1
            listed += n
        if listed <= 32 * (ne + nf) or dims[0] * dims[1] * dims[2] == 1:
            return origin, h, dims, lo, hi
        h *= 2.0


@leaf_njit()
def _cell(x, origin, h, size):  # pragma: no cover - compiled
    """Grid cell of coordinate x on one axis, clipped to [0, size)."""
    return min(max(np.int64(math.floor((x - origin) / h)), np.int64(0)), size - 1)


@njit(cache=True)
def _undecided_edge_face_pairs(v, e, f, origin, h, dims, lo, hi, scale, out):  # pragma: no cover - compiled
    """Rows [edge, face] of every edge/face pair whose closed bounding boxes (``lo``, ``hi`` from :func:`_grid`)
    overlap, that share no vertex and that the float64 orientation filter cannot prove disjoint
    (:func:`_pair_undecided`), written to ``out`` up to its length; returns how many there are (the caller runs again
    with a larger ``out`` when that is more).

    The faces are listed under every grid cell their box overlaps (a counting sort, in increasing face id); each edge
    visits the cells its box overlaps, and a pair is looked at only by the one cell that holds the low corner of the
    two boxes' intersection (cell indices are monotone in the coordinate, so that cell is each box's first cell or
    beyond, and both boxes are listed there): each pair exactly once. Box ends are coordinates (min and max are
    exact), so touching boxes are never lost to rounding."""
    ne, nf = e.shape[0], f.shape[0]
    ncell = dims[0] * dims[1] * dims[2]
    first = np.empty((nf, 3), np.int64)
    last = np.empty((nf, 3), np.int64)
    start = np.zeros(ncell + 1, np.int64)
    for j in range(nf):
        for ax in range(3):
            first[j, ax] = _cell(lo[ne + j, ax], origin[ax], h, dims[ax])
            last[j, ax] = _cell(hi[ne + j, ax], origin[ax], h, dims[ax])
        for ix in range(first[j, 0], last[j, 0] + 1):
            for iy in range(first[j, 1], last[j, 1] + 1):
                for iz in range(first[j, 2], last[j, 2] + 1):
                    start[(ix * dims[1] + iy) * dims[2] + iz + 1] += 1
    for q in range(ncell):
        start[q + 1] += start[q]
    at = start[:-1].copy()
    # the listed faces in list order (the scan below reads them in sequence): id, box lo / hi, first cells, vertices
    items = np.empty(start[ncell], np.int64)
    box = np.empty((start[ncell], 6))
    ints = np.empty((start[ncell], 6), np.int64)
    widest = 0
    for j in range(nf):
        for ix in range(first[j, 0], last[j, 0] + 1):
            for iy in range(first[j, 1], last[j, 1] + 1):
                for iz in range(first[j, 2], last[j, 2] + 1):
                    q = (ix * dims[1] + iy) * dims[2] + iz
                    k = at[q]
                    items[k] = j
                    for ax in range(3):
                        box[k, ax] = lo[ne + j, ax]
                        box[k, 3 + ax] = hi[ne + j, ax]
                        ints[k, ax] = first[j, ax]
                        ints[k, 3 + ax] = f[j, ax]
                    at[q] += 1
    for q in range(ncell):
        widest = max(widest, start[q + 1] - start[q])
    near = np.empty(widest, np.int64)
    found = 0
    for i in range(ne):
        p, r = e[i, 0], e[i, 1]
        lo0, lo1, lo2 = lo[i, 0], lo[i, 1], lo[i, 2]
        hi0, hi1, hi2 = hi[i, 0], hi[i, 1], hi[i, 2]
        c0, d0 = _cell(lo0, origin[0], h, dims[0]), _cell(hi0, origin[0], h, dims[0])
        c1, d1 = _cell(lo1, origin[1], h, dims[1]), _cell(hi1, origin[1], h, dims[1])
        c2, d2 = _cell(lo2, origin[2], h, dims[2]), _cell(hi2, origin[2], h, dims[2])
        for ix in range(c0, d0 + 1):
            for iy in range(c1, d1 + 1):
                for iz in range(c2, d2 + 1):
                    q = (ix * dims[1] + iy) * dims[2] + iz
                    # the cell's faces whose boxes overlap the edge's, that this cell looks at (the cell of the
                    # intersection's low corner: the cell of a max is the max of the cells) and that share no vertex,
                    # gathered without branches (data-dependent branches here, mostly not taken, cost 3 of 4 ms at
                    # bunny_700's frames), then filtered
                    m = 0
                    for k in range(start[q], start[q + 1]):
                        near[m] = k
                        m += (
                            (box[k, 0] <= hi0)
                            & (box[k, 3] >= lo0)
                            & (box[k, 1] <= hi1)
                            & (box[k, 4] >= lo1)
                            & (box[k, 2] <= hi2)
                            & (box[k, 5] >= lo2)
                        )
                    n = 0
                    for t in range(m):
                        k = near[t]
                        near[n] = k
                        a, b, c = ints[k, 3], ints[k, 4], ints[k, 5]
                        n += (
                            (max(c0, ints[k, 0]) == ix)
                            & (max(c1, ints[k, 1]) == iy)
                            & (max(c2, ints[k, 2]) == iz)
                            & (p != a)
                            & (p != b)
                            & (p != c)
                            & (r != a)
                            & (r != b)
                            & (r != c)
                        )
                    for t in range(n):
                        k = near[t]
                        a, b, c = ints[k, 3], ints[k, 4], ints[k, 5]
                        if _pair_undecided(
                            (v[p, 0], v[p, 1], v[p, 2]),
                            (v[r, 0], v[r, 1], v[r, 2]),
                            (v[a, 0], v[a, 1], v[a, 2]),
                            (v[b, 0], v[b, 1], v[b, 2]),
                            (v[c, 0], v[c, 1], v[c, 2]),
                            scale,
                        ):
                            if found < out.shape[0]:
                                out[found, 0] = i
                                out[found, 1] = items[k]
                            found += 1
    return found


@leaf_njit()
def _orient3(a0, a1, a2, b0, b1, b2, c0, c1, c2, d0, d1, d2, scale):  # pragma: no cover - compiled
    """Sign of orient3d(a, b, c, d) = det[b-a, c-a, d-a]; 0 where unsure. Coordinates as scalars: array arguments
    would cost numba two atomic reference-count operations each per call."""
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    v0, v1, v2 = c0 - a0, c1 - a1, c2 - a2
    w0, w1, w2 = d0 - a0, d1 - a1, d2 - a2
    det = u0 * (v1 * w2 - v2 * w1) + u1 * (v2 * w0 - v0 * w2) + u2 * (v0 * w1 - v1 * w0)
    # 1-norms, not 2-norms: no square roots, and a bound at least as large (so at least as cautious)
    nu = abs(u0) + abs(u1) + abs(u2)
    nv = abs(v0) + abs(v1) + abs(v2)
    nw = abs(w0) + abs(w1) + abs(w2)
    bound = _SLACK * (nu * nv * nw + scale * (nu * nv + nv * nw + nu * nw))
    return 1 if det > bound else (-1 if det < -bound else 0)


@leaf_njit()
def _orient2(a0, a1, b0, b1, c0, c1, scale):  # pragma: no cover - compiled
    """Sign of orient2d(a, b, c) = det[b-a, c-a]; 0 where unsure (as ``_sign2``, with 1-norms as ``_orient3``)."""
    u0, u1, v0, v1 = b0 - a0, b1 - a1, c0 - a0, c1 - a1
    det = u0 * v1 - u1 * v0
    nu, nv = abs(u0) + abs(u1), abs(v0) + abs(v1)
    bound = _SLACK * (nu * nv + scale * (nu + nv))
    return 1 if det > bound else (-1 if det < -bound else 0)


@leaf_njit()
def _pair_undecided(p, q, a, b, c, scale):  # pragma: no cover - compiled
    """Whether the float64 orientation tests cannot prove segment (p, q) and triangle (a, b, c) disjoint (points as
    3-tuples; the robust predicate decides those). Both endpoints strictly on one side of the triangle's plane:
    disjoint. Otherwise, not coplanar: disjoint when the segment's line passes the triangle's three edges on certainly
    different sides. (Nearly) coplanar: disjoint when, projected along the normal's largest axis, a triangle edge or
    the segment's line separates them."""
    sp = _orient3(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], p[0], p[1], p[2], scale)
    sq = _orient3(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], q[0], q[1], q[2], scale)
    if sp * sq == 1:
        return False
    if sp != 0 or sq != 0:
        s1 = _orient3(p[0], p[1], p[2], q[0], q[1], q[2], a[0], a[1], a[2], b[0], b[1], b[2], scale)
        s2 = _orient3(p[0], p[1], p[2], q[0], q[1], q[2], b[0], b[1], b[2], c[0], c[1], c[2], scale)
        s3 = _orient3(p[0], p[1], p[2], q[0], q[1], q[2], c[0], c[1], c[2], a[0], a[1], a[2], scale)
        pos = s1 == 1 or s2 == 1 or s3 == 1
        neg = s1 == -1 or s2 == -1 or s3 == -1
        return not (pos and neg)
    # coplanar within the slack: project along the dominant axis of the triangle's normal
    n0 = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
    n1 = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
    n2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    x, y = 1, 2
    if abs(n1) > abs(n0) and abs(n1) >= abs(n2):
        x, y = 0, 2
    elif abs(n2) > abs(n0) and abs(n2) > abs(n1):
        x, y = 0, 1
    for r in range(3):
        t0 = a if r == 0 else (b if r == 1 else c)
        t1 = b if r == 0 else (c if r == 1 else a)
        opp = c if r == 0 else (a if r == 1 else b)
        side = _orient2(t0[x], t0[y], t1[x], t1[y], opp[x], opp[y], scale)
        if (
            side != 0
            and _orient2(t0[x], t0[y], t1[x], t1[y], p[x], p[y], scale) == -side
            and _orient2(t0[x], t0[y], t1[x], t1[y], q[x], q[y], scale) == -side
        ):
            return False
    sa = _orient2(p[x], p[y], q[x], q[y], a[x], a[y], scale)
    sb = _orient2(p[x], p[y], q[x], q[y], b[x], b[y], scale)
    sc = _orient2(p[x], p[y], q[x], q[y], c[x], c[y], scale)
    return not (sa != 0 and sa == sb and sa == sc)


def _undecided(v: np.ndarray, e: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(k, 2) int64 [edge, face] of the box-overlapping pairs sharing no vertex that the float filter leaves open,
    in edge order (faces of one edge in cell order)."""
    origin, h, dims, lo, hi = _grid(v, e, f)
    scale = float(np.abs(v).max())
    out = np.empty((max(64, e.shape[0] // 8), 2), np.int64)
    n = _undecided_edge_face_pairs(v, e, f, origin, h, dims, lo, hi, scale, out)
    if n > out.shape[0]:  # more than room for: once more with room for all
        out = np.empty((n, 2), np.int64)
        _undecided_edge_face_pairs(v, e, f, origin, h, dims, lo, hi, scale, out)
    return out[:n]


def _confirmed(v: np.ndarray, e: np.ndarray, f: np.ndarray, pairs: np.ndarray, first_only: bool = False) -> list[int]:
    """Rows of ``pairs`` that ipctk's robust predicate finds intersecting (only the first when ``first_only``)."""
    import ipctk

    found = []
    for k, (i, j) in enumerate(pairs.tolist()):  # the few pairs the float filter could not reject
        p, q, (a, b, c) = e[i, 0], e[i, 1], f[j]
        if ipctk.is_edge_intersecting_triangle(v[p], v[q], v[a], v[b], v[c]):
            found.append(k)
            if first_only:
                break
    return found


def _indices(vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray):
    v, e = _check(vertices, edges, 3, 2, "edges")
    _, f = _check(v, faces, 3, 3, "faces")
    return v, np.ascontiguousarray(e), np.ascontiguousarray(f)


def find_intersecting_pairs(vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(edge_index, face_index) pairs, (k, 2) int64, of surface edges crossing or touching
    triangles, excluding pairs that share a vertex. Sorted by edge then face."""
    v, e, f = _indices(vertices, edges, faces)
    if e.shape[0] == 0 or f.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = _undecided(v, e, f)
    pairs = pairs[np.asarray(_confirmed(v, e, f, pairs), dtype=np.int64)]
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def has_intersections(vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray) -> bool:
    """Whether some surface edge crosses or touches a triangle it shares no vertex with (the test of
    :func:`find_intersecting_pairs`, stopping at the first pair ipctk's robust predicate confirms)."""
    v, e, f = _indices(vertices, edges, faces)
    if e.shape[0] == 0 or f.shape[0] == 0:
        return False
    return bool(_confirmed(v, e, f, _undecided(v, e, f), first_only=True))


def _segment_candidates(v: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Pairs (i < j) of segments whose bounding boxes overlap."""
    p, q = v[s[:, 0]], v[s[:, 1]]
    lo, hi = np.minimum(p, q), np.maximum(p, q)
    length = np.linalg.norm(q - p, axis=1)
    # Long segments would blow up the k-d tree radius: test them against everything directly.
    long_mask = length > 4.0 * np.median(length)
    short = np.flatnonzero(~long_mask)
    chunks = []
    if short.size > 1:
        mid = 0.5 * (p[short] + q[short])
        radius = float(length[short].max()) * (1.0 + 1e-9)
        from scipy.spatial import cKDTree  # 2D only: spares 3D runs ≈ 40 ms and ≈ 7 MB at start

        kd = cKDTree(mid)
        pairs = kd.query_pairs(radius, output_type="ndarray")
        if pairs.size:
            chunks.append(short[pairs])
    for i in np.flatnonzero(long_mask):  # loop over the (few) long segments only
        overlap = np.all((lo <= hi[i]) & (hi >= lo[i]), axis=1)
        overlap[i] = False
        j = np.flatnonzero(overlap)
        j = j[~long_mask[j] | (j > i)]  # long-long pairs once
        chunks.append(np.stack([np.full(j.size, i), j], axis=1))
    if not chunks:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(np.concatenate(chunks).astype(np.int64), axis=1)
    pairs = np.unique(pairs, axis=0)
    first, second = pairs[:, 0], pairs[:, 1]
    overlap = np.all((lo[first] <= hi[second]) & (hi[first] >= lo[second]), axis=1)
    return pairs[overlap]


def find_intersecting_segments(vertices: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Pairs (i, j), i < j, (k, 2) int64, of 2D segments that cross, touch or overlap,
    excluding pairs that share a vertex. Sorted by i then j."""
    v, s = _check(vertices, segments, 2, 2, "segments")
    empty = np.zeros((0, 2), dtype=np.int64)
    if s.shape[0] < 2:
        return empty
    pairs = _segment_candidates(v, s)
    if pairs.size == 0:
        return empty
    a, b = s[pairs[:, 0]], s[pairs[:, 1]]
    shares = (a[:, :, None] == b[:, None, :]).any(axis=(1, 2))
    pairs, a, b = pairs[~shares], a[~shares], b[~shares]
    if pairs.size == 0:
        return empty

    scale = float(np.abs(v).max())
    p1, q1, p2, q2 = v[a[:, 0]], v[a[:, 1]], v[b[:, 0]], v[b[:, 1]]
    o1, o2 = _sign2(p1, q1, p2, scale), _sign2(p1, q1, q2, scale)
    o3, o4 = _sign2(p2, q2, p1, scale), _sign2(p2, q2, q1, scale)
    reject = _same(o1, o2) | _same(o3, o4)

    import ipctk

    keep = np.flatnonzero(~reject)
    confirmed = [
        i for i in keep if ipctk.segment_segment_intersect(p1[i], q1[i], p2[i], q2[i])
    ]  # loop over the pairs the vectorised filter could not reject
    if not confirmed:
        return empty
    out = pairs[np.asarray(confirmed, dtype=np.int64)]
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def surface_intersecting_pairs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Intersecting primitive pairs of one surface: (edge, face) pairs for triangles (edges
    from :func:`idp.mesh.surface.unique_edges`), (segment, segment) pairs for 2D polylines."""
    from idp.mesh.surface import unique_edges

    f = np.asarray(faces)
    if f.ndim == 2 and f.shape[1] == 2:
        return find_intersecting_segments(vertices, f)
    _, f = _check(vertices, f, 3, 3, "faces")
    return find_intersecting_pairs(vertices, unique_edges(f), f)


def count_intersections(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Number of intersecting primitive pairs of a triangle surface or 2D polyline."""
    return int(surface_intersecting_pairs(vertices, faces).shape[0])


def _ordered_pair(p: tuple[int, ...], q: tuple[int, ...]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The two keys in sorted order (what ``tuple(sorted((p, q)))`` gives, typed as a pair)."""
    return (p, q) if p <= q else (q, p)


# The last few answers of intersecting_pair_keys by a digest of their input: a repaired frame is checked by its
# certificate and again by the repair report (0.1 s each on the 25K-triangle mannequin).
_RECENT_KEYS: collections.OrderedDict[bytes, frozenset] = collections.OrderedDict()
_RECENT_KEYS_SIZE = 4


def intersecting_pair_keys(vertices: np.ndarray, faces: np.ndarray) -> set[tuple[tuple[int, ...], tuple[int, ...]]]:
    """The intersecting primitive pairs of a surface as vertex-id keys that do not depend on edge numbering:
    ((sorted edge vertices), (sorted triangle vertices)) in 3D, ((segment a), (segment b)) sorted in 2D.
    The same vertices and faces (bit for bit) asked again soon are answered from a small memo."""
    v = np.ascontiguousarray(vertices)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    digest = hashlib.blake2b(digest_size=20)
    for part in (str((v.dtype.str, v.shape, f.shape)).encode(), v.tobytes(), f.tobytes()):
        digest.update(part)
    key = digest.digest()
    if key in _RECENT_KEYS:
        _RECENT_KEYS.move_to_end(key)
        return set(_RECENT_KEYS[key])
    keys = _intersecting_pair_keys(v, f)
    _RECENT_KEYS[key] = frozenset(keys)
    while len(_RECENT_KEYS) > _RECENT_KEYS_SIZE:
        _RECENT_KEYS.popitem(last=False)
    return keys


def _intersecting_pair_keys(vertices: np.ndarray, f: np.ndarray) -> set[tuple[tuple[int, ...], tuple[int, ...]]]:
    from idp.mesh.surface import unique_edges

    if f.ndim == 2 and f.shape[1] == 2:
        pairs = find_intersecting_segments(vertices, f)
        a, b = np.sort(f[pairs[:, 0]], axis=1), np.sort(f[pairs[:, 1]], axis=1)
        return {_ordered_pair(tuple(p), tuple(q)) for p, q in zip(a.tolist(), b.tolist(), strict=True)}
    _, f = _check(vertices, f, 3, 3, "faces")
    e = unique_edges(f)  # once: the pairs index it and the keys read it
    pairs = find_intersecting_pairs(vertices, e, f)
    a, b = np.sort(e[pairs[:, 0]], axis=1), np.sort(f[pairs[:, 1]], axis=1)
    return {(tuple(p), tuple(q)) for p, q in zip(a.tolist(), b.tolist(), strict=True)}


def pairs_within(keys: set[tuple[tuple[int, ...], tuple[int, ...]]], vertices: np.ndarray) -> int:
    """How many pair keys (of :func:`intersecting_pair_keys`) have every vertex of both primitives in the (n,) bool
    mask ``vertices`` (a prescribed group's own crossings)."""
    return sum(1 for a, b in keys if vertices[list(a)].all() and vertices[list(b)].all())
