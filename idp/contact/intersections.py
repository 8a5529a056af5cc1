"""Exact-enough detection of intersecting surface primitives (the input sanity check).

IPC needs an intersection-free start state: a surface edge that crosses a surface triangle
(3D) or two boundary segments that cross (2D) make the barrier undefined. Detection runs in
three stages: a broad phase (ipctk's LBVH in 3D, a k-d tree in 2D), a vectorised float64
orientation filter that rejects the pairs it can prove disjoint, and ipctk's robust
predicates as the final word on every pair the filter could not reject.
Pairs of primitives that share a vertex are never reported (they touch by construction).
"""

from __future__ import annotations

import collections
import hashlib
from operator import attrgetter

import numpy as np

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


def _sign3(a, b, c, d, scale: float) -> np.ndarray:
    """Sign of orient3d(a, b, c, d) = det[b-a, c-a, d-a] per row; 0 where unsure."""
    u, v, w = b - a, c - a, d - a
    det = np.einsum("ij,ij->i", u, np.cross(v, w))
    nu, nv, nw = (np.linalg.norm(x, axis=1) for x in (u, v, w))
    bound = _SLACK * (nu * nv * nw + scale * (nu * nv + nv * nw + nu * nw))
    return np.where(det > bound, 1, np.where(det < -bound, -1, 0))


def _sign2(a, b, c, scale: float) -> np.ndarray:
    """Sign of orient2d(a, b, c) = det[b-a, c-a] per row; 0 where unsure."""
    u, v = b - a, c - a
    det = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
    bound = _SLACK * (nu * nv + scale * (nu + nv))
    return np.where(det > bound, 1, np.where(det < -bound, -1, 0))


def _mixed(*signs: np.ndarray) -> np.ndarray:
    """True where the signs certainly disagree (some sure +1 and some sure -1)."""
    s = np.stack(signs, axis=1)
    return (s == 1).any(axis=1) & (s == -1).any(axis=1)


def _same(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """True where both signs are sure and equal (both points strictly on one side)."""
    return (s1 * s2) == 1


def _coplanar_disjoint(p, q, a, b, c, scale: float) -> np.ndarray:
    """For (nearly) coplanar edge/triangle pairs: True where a 2D separating line proves them disjoint."""
    n = np.cross(b - a, c - a)
    drop = np.argmax(np.abs(n), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]  # project along the dominant normal axis
    rows = np.arange(p.shape[0])[:, None]
    P, Q, A, B, C = (x[rows, keep] for x in (p, q, a, b, c))
    out = np.zeros(p.shape[0], dtype=bool)
    for x0, x1, opp in ((A, B, C), (B, C, A), (C, A, B)):
        side = _sign2(x0, x1, opp, scale)  # inside of this triangle edge
        sp, sq = _sign2(x0, x1, P, scale), _sign2(x0, x1, Q, scale)
        out |= (side != 0) & (sp == -side) & (sq == -side)
    sa, sb, sc = (_sign2(P, Q, x, scale) for x in (A, B, C))
    out |= (sa == sb) & (sb == sc) & (sa != 0)
    return out


def _edge_face_candidates(v: np.ndarray, e: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import ipctk

    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    bp = ipctk.LBVH()
    # A hair of inflation so exactly touching boxes are never lost to rounding.
    bp.build(v, e.astype(np.int32), f.astype(np.int32), 1e-12 * diag)
    cands = bp.detect_edge_face_candidates()
    if not cands:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # ipctk hands back a list of candidate objects: two attribute sweeps (half the time of a list of tuples)
    edge_ids = np.fromiter(map(attrgetter("edge_id"), cands), dtype=np.int64, count=len(cands))
    face_ids = np.fromiter(map(attrgetter("face_id"), cands), dtype=np.int64, count=len(cands))
    return edge_ids, face_ids


def find_intersecting_pairs(vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(edge_index, face_index) pairs, (k, 2) int64, of surface edges crossing or touching
    triangles, excluding pairs that share a vertex. Sorted by edge then face."""
    v, e = _check(vertices, edges, 3, 2, "edges")
    _, f = _check(v, faces, 3, 3, "faces")
    empty = np.zeros((0, 2), dtype=np.int64)
    if e.shape[0] == 0 or f.shape[0] == 0:
        return empty
    ei, fi = _edge_face_candidates(v, e, f)
    if ei.size == 0:
        return empty
    ev, fv = e[ei], f[fi]
    shares = (ev[:, :, None] == fv[:, None, :]).any(axis=(1, 2))
    ei, fi, ev, fv = ei[~shares], fi[~shares], ev[~shares], fv[~shares]
    if ei.size == 0:
        return empty

    scale = float(np.abs(v).max())
    p, q = v[ev[:, 0]], v[ev[:, 1]]
    a, b, c = v[fv[:, 0]], v[fv[:, 1]], v[fv[:, 2]]
    sp, sq = _sign3(a, b, c, p, scale), _sign3(a, b, c, q, scale)
    coplanar = (sp == 0) & (sq == 0)
    reject = _same(sp, sq)
    general = ~reject & ~coplanar
    if general.any():
        g = np.flatnonzero(general)
        s1 = _sign3(p[g], q[g], a[g], b[g], scale)
        s2 = _sign3(p[g], q[g], b[g], c[g], scale)
        s3 = _sign3(p[g], q[g], c[g], a[g], scale)
        reject[g] = _mixed(s1, s2, s3)
    if coplanar.any():
        cp = np.flatnonzero(coplanar)
        reject[cp] = _coplanar_disjoint(p[cp], q[cp], a[cp], b[cp], c[cp], scale)

    import ipctk

    keep = np.flatnonzero(~reject)
    confirmed = [
        i for i in keep if ipctk.is_edge_intersecting_triangle(p[i], q[i], a[i], b[i], c[i])
    ]  # loop over the few pairs the vectorised filter could not reject
    if not confirmed:
        return empty
    idx = np.asarray(confirmed, dtype=np.int64)
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

    pairs = surface_intersecting_pairs(vertices, f)
    if len(pairs) == 0:
        return set()
    if f.shape[1] == 2:
        a, b = np.sort(f[pairs[:, 0]], axis=1), np.sort(f[pairs[:, 1]], axis=1)
        keys = {_ordered_pair(tuple(p), tuple(q)) for p, q in zip(a.tolist(), b.tolist(), strict=True)}
    else:
        e = unique_edges(f)
        a, b = np.sort(e[pairs[:, 0]], axis=1), np.sort(f[pairs[:, 1]], axis=1)
        keys = {(tuple(p), tuple(q)) for p, q in zip(a.tolist(), b.tolist(), strict=True)}
    return keys


def pairs_within(keys: set[tuple[tuple[int, ...], tuple[int, ...]]], vertices: np.ndarray) -> int:
    """How many pair keys (of :func:`intersecting_pair_keys`) have every vertex of both primitives in the (n,) bool
    mask ``vertices`` (a prescribed group's own crossings)."""
    return sum(1 for a, b in keys if vertices[list(a)].all() and vertices[list(b)].all())
