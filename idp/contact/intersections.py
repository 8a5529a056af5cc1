"""Exact-enough detection of intersecting surface primitives (the input sanity check).

IPC needs an intersection-free start state: a surface edge that crosses a surface triangle
(3D) or two boundary segments that cross (2D) make the barrier undefined. Detection runs in
three stages: a broad phase (a uniform grid over the bounding boxes in 3D, a k-d tree in 2D),
a float64 orientation filter that rejects the pairs it can prove disjoint (compiled in 3D,
vectorised in 2D), and ipctk's robust predicates as the final word on every pair the filter
could not reject. Pairs of primitives that share a vertex are never reported (they touch by
construction).

The 3D broad phase is its own code, not the solver's contact grid (``idp.contact._broad_phase``), so the
certificate of a run in preserve mode does not lean on what it checks. It replaced ipctk's LBVH here
because that hands its candidates back as one Python object each: on the Fig. 12 cat's last frame
(63 K candidates) building them and reading their ids took 80 of the function's 170 ms.
"""

from __future__ import annotations

import collections
import hashlib

import numpy as np
from numba import njit

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


@njit(cache=True, inline="always")
def _overlaps(fbox, kb, lo0, lo1, lo2, hi0, hi1, hi2):  # pragma: no cover - compiled
    """Whether listed face box ``kb`` of ``fbox`` (6, entries) overlaps the closed box [lo, hi] (no branches)."""
    return (
        (fbox[0, kb] <= hi0)
        & (fbox[3, kb] >= lo0)
        & (fbox[1, kb] <= hi1)
        & (fbox[4, kb] >= lo1)
        & (fbox[2, kb] <= hi2)
        & (fbox[5, kb] >= lo2)
    )


@njit(cache=True)
def _count_overlaps(ebox, fbox, estart, fstart):  # pragma: no cover - compiled
    """How many (edge, face) entries listed under a common cell have overlapping boxes (an upper bound on the pairs
    ``_list_pairs`` reports; a loop without data-dependent branches, which the compiler vectorises)."""
    total = 0
    for q in range(estart.size - 1):
        for ka in range(estart[q], estart[q + 1]):
            lo0, lo1, lo2 = ebox[0, ka], ebox[1, ka], ebox[2, ka]
            hi0, hi1, hi2 = ebox[3, ka], ebox[4, ka], ebox[5, ka]
            for kb in range(fstart[q], fstart[q + 1]):
                total += _overlaps(fbox, kb, lo0, lo1, lo2, hi0, hi1, hi2)
    return total


@njit(cache=True)
def _list_pairs(ebox, fbox, eint, fint, estart, eitems, fstart, fitems, dims, ei, fi):  # pragma: no cover - compiled
    """Write the (edge, face) pairs to ei, fi cell by cell and return how many: those whose boxes overlap, that the
    cell holding the low corner of the boxes' intersection reports, and that share no vertex. ``ebox``, ``fbox``
    (6, entries): the listed boxes' lo0 lo1 lo2 hi0 hi1 hi2 in list order; ``eint`` (5, entries), ``fint``
    (6, entries): their first cells per axis and their vertices, likewise (read in sequence)."""
    found = 0
    for q in range(estart.size - 1):
        if estart[q] == estart[q + 1] or fstart[q] == fstart[q + 1]:
            continue
        iz = q % dims[2]
        iy = (q // dims[2]) % dims[1]
        ix = q // (dims[2] * dims[1])
        for ka in range(estart[q], estart[q + 1]):
            lo0, lo1, lo2 = ebox[0, ka], ebox[1, ka], ebox[2, ka]
            hi0, hi1, hi2 = ebox[3, ka], ebox[4, ka], ebox[5, ka]
            a, b = eint[3, ka], eint[4, ka]
            for kb in range(fstart[q], fstart[q + 1]):
                if not _overlaps(fbox, kb, lo0, lo1, lo2, hi0, hi1, hi2):
                    continue
                keep = (
                    # the cell of the intersection's low corner reports the pair (the cell of a max: the max of cells)
                    (max(eint[0, ka], fint[0, kb]) == ix)
                    & (max(eint[1, ka], fint[1, kb]) == iy)
                    & (max(eint[2, ka], fint[2, kb]) == iz)
                    # and no shared vertex
                    & (a != fint[3, kb])
                    & (a != fint[4, kb])
                    & (a != fint[5, kb])
                    & (b != fint[3, kb])
                    & (b != fint[4, kb])
                    & (b != fint[5, kb])
                )
                if keep:
                    ei[found] = eitems[ka]
                    fi[found] = fitems[kb]
                    found += 1
    return found


def _cell_ranges(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, h: float, dims: np.ndarray):
    """(first, last) (k, 3) int64: the grid cells each box [lo, hi] overlaps, per axis (clipped to the grid)."""
    first = np.clip(np.floor((lo - origin) / h), 0, dims - 1).astype(np.int64)
    last = np.clip(np.floor((hi - origin) / h), 0, dims - 1).astype(np.int64)
    return first, last


def _cell_lists(first: np.ndarray, last: np.ndarray, dims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(start, items): box ids listed under every cell they overlap, as compressed rows per cell id
    (ix·dims1 + iy)·dims2 + iz; within a cell in increasing box id."""
    span = last - first + 1
    count = span.prod(axis=1)
    box = np.repeat(np.arange(first.shape[0], dtype=np.int64), count)
    local = np.arange(box.size, dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
    sy, sz = span[box, 1], span[box, 2]
    ix = first[box, 0] + local // (sy * sz)
    iy = first[box, 1] + (local // sz) % sy
    iz = first[box, 2] + local % sz
    cell = (ix * dims[1] + iy) * dims[2] + iz
    order = np.argsort(cell, kind="stable")
    start = np.zeros(int(dims.prod()) + 1, dtype=np.int64)
    np.cumsum(np.bincount(cell, minlength=start.size - 1), out=start[1:])
    return start, box[order]


def _edge_face_box_pairs(v: np.ndarray, e: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edge ids, face ids) of every edge/face pair whose closed bounding boxes overlap and which share no vertex.

    A uniform grid (cells about twice the mean edge box, the grid at most four cells per box, coarser while the
    cell lists would hold more than 32 entries per box): every box is listed under each cell it overlaps, and a pair
    is reported by the one cell that holds the low corner of the two boxes' intersection (cell indices are monotone in
    the coordinate, so that cell is each box's first cell or beyond, and both boxes are listed there): each pair
    exactly once. Box ends are coordinates (min and max are exact), so touching boxes are never lost to rounding."""
    ne, nf = e.shape[0], f.shape[0]
    e0, e1 = v[e[:, 0]], v[e[:, 1]]
    elo, ehi = np.minimum(e0, e1), np.maximum(e0, e1)
    f0, f1, f2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    flo, fhi = np.minimum(np.minimum(f0, f1), f2), np.maximum(np.maximum(f0, f1), f2)
    origin = np.minimum(elo.min(axis=0), flo.min(axis=0))
    extent = np.maximum(ehi.max(axis=0), fhi.max(axis=0)) - origin
    h = 2.0 * float((ehi - elo).max(axis=1).mean())
    if not h > 0.0:  # every edge a point: one cell per axis
        h = max(float(extent.max()), 1.0)
    cells = float(np.prod(np.floor(extent / h) + 1.0))
    if cells > 4.0 * (ne + nf):
        h *= (cells / (4.0 * (ne + nf))) ** (1.0 / 3.0)
    while True:  # boxes far larger than the mean (long spokes of a fan) are listed under many cells
        dims = (np.floor(extent / h) + 1).astype(np.int64)
        ef, el = _cell_ranges(elo, ehi, origin, h, dims)
        ff, fl = _cell_ranges(flo, fhi, origin, h, dims)
        listed = int((el - ef + 1).prod(axis=1).sum() + (fl - ff + 1).prod(axis=1).sum())
        if listed <= 32 * (ne + nf) or dims.prod() == 1:
            break
        h *= 2.0
    estart, eitems = _cell_lists(ef, el, dims)
    fstart, fitems = _cell_lists(ff, fl, dims)
    ebox = np.ascontiguousarray(np.concatenate([elo, ehi], axis=1)[eitems].T)
    fbox = np.ascontiguousarray(np.concatenate([flo, fhi], axis=1)[fitems].T)
    eint = np.ascontiguousarray(np.concatenate([ef, e], axis=1)[eitems].T)
    fint = np.ascontiguousarray(np.concatenate([ff, f], axis=1)[fitems].T)
    bound = _count_overlaps(ebox, fbox, estart, fstart)
    ei = np.empty(bound, dtype=np.int64)
    fi = np.empty(bound, dtype=np.int64)
    n = _list_pairs(ebox, fbox, eint, fint, estart, eitems, fstart, fitems, dims, ei, fi)
    ei, fi = ei[:n].copy(), fi[:n].copy()
    return ei, fi


@njit(cache=True)
def _orient3(a, b, c, d, scale):  # pragma: no cover - compiled
    """Sign of orient3d(a, b, c, d) = det[b-a, c-a, d-a]; 0 where unsure ."""
    u0, u1, u2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    v0, v1, v2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    w0, w1, w2 = d[0] - a[0], d[1] - a[1], d[2] - a[2]
    det = u0 * (v1 * w2 - v2 * w1) + u1 * (v2 * w0 - v0 * w2) + u2 * (v0 * w1 - v1 * w0)
    nu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    nv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    bound = _SLACK * (nu * nv * nw + scale * (nu * nv + nv * nw + nu * nw))
    return 1 if det > bound else (-1 if det < -bound else 0)


@njit(cache=True)
def _orient2(a0, a1, b0, b1, c0, c1, scale):  # pragma: no cover - compiled
    """Sign of orient2d(a, b, c) = det[b-a, c-a]; 0 where unsure (as ``_sign2``)."""
    u0, u1, v0, v1 = b0 - a0, b1 - a1, c0 - a0, c1 - a1
    det = u0 * v1 - u1 * v0
    nu, nv = np.sqrt(u0 * u0 + u1 * u1), np.sqrt(v0 * v0 + v1 * v1)
    bound = _SLACK * (nu * nv + scale * (nu + nv))
    return 1 if det > bound else (-1 if det < -bound else 0)


@njit(cache=True)
def _unresolved_pairs(v, e, f, ei, fi, scale):  # pragma: no cover - compiled
    """True for the candidate pairs that the float64 orientation tests cannot prove disjoint (the robust predicate
    decides those). Both endpoints strictly on one side of the triangle's plane: disjoint. Otherwise, not coplanar:
    disjoint when the edge's line passes the triangle's three edges on certainly different sides. (Nearly) coplanar:
    disjoint when, projected along the normal's largest axis, a triangle edge or the segment's line separates them."""
    n = ei.size
    out = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        p, q = v[e[ei[k], 0]], v[e[ei[k], 1]]
        a, b, c = v[f[fi[k], 0]], v[f[fi[k], 1]], v[f[fi[k], 2]]
        sp, sq = _orient3(a, b, c, p, scale), _orient3(a, b, c, q, scale)
        if sp * sq == 1:
            continue
        if sp != 0 or sq != 0:
            s1 = _orient3(p, q, a, b, scale)
            s2 = _orient3(p, q, b, c, scale)
            s3 = _orient3(p, q, c, a, scale)
            pos = s1 == 1 or s2 == 1 or s3 == 1
            neg = s1 == -1 or s2 == -1 or s3 == -1
            out[k] = not (pos and neg)
            continue
        # coplanar within the slack: project along the dominant axis of the triangle's normal
        n0 = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
        n1 = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
        n2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        x, y = 1, 2
        if abs(n1) > abs(n0) and abs(n1) >= abs(n2):
            x, y = 0, 2
        elif abs(n2) > abs(n0) and abs(n2) > abs(n1):
            x, y = 0, 1
        disjoint = False
        for r in range(3):
            t0 = (a, b, c)[r]
            t1 = (b, c, a)[r]
            opp = (c, a, b)[r]
            side = _orient2(t0[x], t0[y], t1[x], t1[y], opp[x], opp[y], scale)
            s_p = _orient2(t0[x], t0[y], t1[x], t1[y], p[x], p[y], scale)
            s_q = _orient2(t0[x], t0[y], t1[x], t1[y], q[x], q[y], scale)
            if side != 0 and s_p == -side and s_q == -side:
                disjoint = True
        sa = _orient2(p[x], p[y], q[x], q[y], a[x], a[y], scale)
        sb = _orient2(p[x], p[y], q[x], q[y], b[x], b[y], scale)
        sc = _orient2(p[x], p[y], q[x], q[y], c[x], c[y], scale)
        if sa == sb and sb == sc and sa != 0:
            disjoint = True
        out[k] = not disjoint
    return out


def find_intersecting_pairs(vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(edge_index, face_index) pairs, (k, 2) int64, of surface edges crossing or touching
    triangles, excluding pairs that share a vertex. Sorted by edge then face."""
    v, e = _check(vertices, edges, 3, 2, "edges")
    _, f = _check(v, faces, 3, 3, "faces")
    empty = np.zeros((0, 2), dtype=np.int64)
    if e.shape[0] == 0 or f.shape[0] == 0:
        return empty
    e, f = np.ascontiguousarray(e), np.ascontiguousarray(f)
    ei, fi = _edge_face_box_pairs(v, e, f)
    if ei.size == 0:
        return empty
    keep = np.flatnonzero(_unresolved_pairs(v, e, f, ei, fi, float(np.abs(v).max())))

    import ipctk

    ev, fv = e[ei[keep]], f[fi[keep]]
    confirmed = [
        k
        for k in range(keep.size)
        if ipctk.is_edge_intersecting_triangle(v[ev[k, 0]], v[ev[k, 1]], v[fv[k, 0]], v[fv[k, 1]], v[fv[k, 2]])
    ]  # loop over the few pairs the filter could not reject
    if not confirmed:
        return empty
    idx = keep[np.asarray(confirmed, dtype=np.int64)]
    pairs = np.stack([ei[idx], fi[idx]], axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


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
