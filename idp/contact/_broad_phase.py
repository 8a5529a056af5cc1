"""Numba broad phase for 3D triangle surfaces: face-vertex and edge-edge candidates as int arrays.

ipctk's Python bindings hand candidates back as lists of Python objects (~10 ms per 10K pairs to
turn into arrays); :func:`surface_candidates` produces the arrays directly.

Rule. Each primitive (vertex, edge, face) has the axis-aligned box [lo, hi] of its vertices (at
V0, and also at V1 for a linear sweep). A pair is reported iff, on every axis,
``lo_a <= hi_b + inflation and lo_b <= hi_a + inflation``, evaluated literally (``hi + inflation``
is rounded once and stored), so a brute force implementing the same expression gets the same set.
Never reported: a face with one of its own vertices, two edges sharing a vertex, pairs whose
vertices are all static (id >= num_dynamic, or marked still for the query), and pairs whose vertices
are all in the query's ``group``.

Algorithm: a dense uniform grid over the region the dynamic primitives reach, cell edge = 1.2 x
the mean largest box side of the dynamic edges + inflation. Every primitive is binned (parallel,
stable counting sort) into each cell that its interval [lo, hi + inflation] covers on all three
axes, so two primitives passing the test always share a cell. Static primitives that miss the
dynamic region are dropped and the others are clipped to it, so a large static cage costs only
what it covers there. Primitives are binned in the order vertices, edges, faces, and within each
type dynamic outside the group, dynamic in the group, static outside, static in the group (a
primitive is "in the group" when all its vertices are), so each cell's list comes out grouped by
class; a cell copies its entries into small contiguous scratch arrays and tests, branch-free, every
dyn-dyn and dyn-static edge pair and every dynamic face x vertex and static face x dynamic vertex
pair, except group x group pairs (static-static and group-group pairs are never looked at: the
mannequin's moving head, 6,348 of 12,811 vertices, made 21 M head-head tests per sweep, 0.3-0.9 s,
before its class was skipped). A pair sharing several cells is emitted only by
the cell holding the low corner of the intersection of their intervals (c = max of their first
cells, per axis: an exact integer test, done as a 3-bit mask per entry), so there are no
duplicates and no sort is needed.

Parallelism: boxes, binning and the cell loop are prange loops over a few work-balanced chunks
(numba's thread count is left alone; no np.zeros in the parallel functions, each would be one more
parallel region, ~50 us of worker wake-up under OMP_WAIT_POLICY=PASSIVE). Each chunk of cells
writes into its own slice of the output buffers; a chunk that finds more pairs than its slice
holds (the slice holds as many rows as the chunk has cell entries, plus 256) makes the pass rerun
with exact slices. Output order is deterministic (by cell, then by position in the cell) but not
sorted.

bunny_3376, last recorded state (3376 dynamic + 386 static vertices, 38K pairs), 2 cores:
2.2 ms (3.8 ms on one thread); ipctk's LBVH build 4.6 ms, plus 32 ms to turn its 40K candidate
objects into arrays.
Tried and dropped (times of the cell-pair kernel, one thread, unless noted): short-circuit
tests reading the global arrays (7.2 ms) -> branch-free tests on per-cell scratch copies (2.4 ms);
grouping each cell's entries by the 3-bit owner mask so only owner-valid pairs are tested
(2.9 ms: fewer tests, more loop overhead); structure-of-arrays scratch with a vectorisable flag
pass (3.1 ms); packed per-primitive records (no gain); a 2D column grid with sort-and-sweep
along the longest axis (216K instead of 342K tests but 5 ms for sort + sweep); dynamic prange
scheduling via numba.set_parallel_chunksize (slower: it also chunks numba's internal array loops,
and defeats caching).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

# Cell edge = _CELL_SCALE * (mean largest box side of the dynamic edges) + inflation
# (bunny_3376, 2 threads: 0.8 -> 2.50 ms, 1.0 -> 2.31, 1.2 -> 2.18, 1.4 -> 2.20, 1.7 -> 2.46, 2.0 -> 3.83).
_CELL_SCALE = 1.2
# The grid is dense: never more cells than this many per primitive (the cell grows instead).
_CELLS_PER_PRIM = 4
_CHUNKS_PER_THREAD = 4
# Output rows reserved per chunk of cells: its number of cell entries plus this.
_SPARE_ROWS = 256

_EMPTY = np.empty((0, 2), dtype=np.int32)

# Primitive classes: 4 x type (vertex, edge, face) + (dynamic outside the group, dynamic in it, static outside,
# static in it).
NUM_KINDS = 12


@njit(cache=True, parallel=True)
def _boxes(V0, V1, sweep, E, F, nd, still, infl, nt):  # pragma: no cover
    """Per primitive g (vertices, then edges, then faces): lo, H = hi + infl, kind = 4 type + class (type 0/1/2
    vertex/edge/face; class 0 dynamic outside the group, 1 dynamic in it, 2 static outside, 3 static in it; a
    vertex is dynamic when its id < nd and bit 0 of ``still`` (still) is 0 for it, an edge or face when one of its
    vertices is), grp[g] = 8 when bit 1 of ``still`` (in the group whose pairs among themselves are skipped) is set
    for every vertex of g, else 0; ri = (vertex ids, padded with -1; own id).
    ext[t] = this chunk's (min dynamic lo (3), max dynamic H (3), sum of the dynamic edges'
    largest box side, their count, the same for the dynamic faces, 1 if it saw a non-finite
    coordinate, 1 if it saw a vertex id outside [0, nv)); kcnt[t] = its count per kind."""
    nv = V0.shape[0]
    ne = E.shape[0]
    n = nv + ne + F.shape[0]
    lo = np.empty((n, 3))
    H = np.empty((n, 3))
    kind = np.empty(n, dtype=np.int8)
    grp = np.empty(n, dtype=np.int32)
    ri = np.empty((n, 4), dtype=np.int32)
    ext = np.empty((nt, 12))
    kcnt = np.empty((nt, NUM_KINDS), dtype=np.int64)  # np.zeros here would be a parallel region of its own
    for t in prange(nt):
        for k in range(NUM_KINDS):
            kcnt[t, k] = 0
        m0 = np.inf
        m1 = np.inf
        m2 = np.inf
        x0 = -np.inf
        x1 = -np.inf
        x2 = -np.inf
        side_e = 0.0
        cnt_e = 0.0
        side_f = 0.0
        cnt_f = 0.0
        bad = 0.0
        bad_ids = 0.0
        for g in range(t * n // nt, (t + 1) * n // nt):
            if g < nv:
                k = 1
                i = g
                ri[g, 0] = g
                ri[g, 1] = -1
                ri[g, 2] = -1
                d = g < nd and (still[g] & 1) == 0
                ing = (still[g] & 2) != 0
            elif g < nv + ne:
                k = 2
                i = g - nv
                ri[g, 0] = E[i, 0]
                ri[g, 1] = E[i, 1]
                ri[g, 2] = -1
            else:
                k = 3
                i = g - nv - ne
                ri[g, 0] = F[i, 0]
                ri[g, 1] = F[i, 1]
                ri[g, 2] = F[i, 2]
            if k > 1:
                d = False
                ing = True
                for j in range(k):
                    v = ri[g, j]
                    if v < 0 or v >= nv:
                        bad_ids = 1.0
                        ri[g, j] = 0
                        ing = False
                    else:
                        d = d or (v < nd and (still[v] & 1) == 0)
                        ing = ing and (still[v] & 2) != 0
            grp[g] = 8 if ing else 0
            ri[g, 3] = i
            for a in range(3):
                v = ri[g, 0]
                lw = V0[v, a]
                hg = lw
                if sweep:
                    x = V1[v, a]
                    lw = min(lw, x)
                    hg = max(hg, x)
                for j in range(1, k):
                    v = ri[g, j]
                    x = V0[v, a]
                    lw = min(lw, x)
                    hg = max(hg, x)
                    if sweep:
                        x = V1[v, a]
                        lw = min(lw, x)
                        hg = max(hg, x)
                if k == 1 and not (np.isfinite(lw) and np.isfinite(hg)):
                    bad = 1.0
                lo[g, a] = lw
                H[g, a] = hg + infl
            kk = 4 * (k - 1) + (0 if d else 2) + (1 if ing else 0)
            kind[g] = kk
            kcnt[t, kk] += 1
            if d:
                m0 = min(m0, lo[g, 0])
                m1 = min(m1, lo[g, 1])
                m2 = min(m2, lo[g, 2])
                x0 = max(x0, H[g, 0])
                x1 = max(x1, H[g, 1])
                x2 = max(x2, H[g, 2])
                if k > 1:
                    sd = max(H[g, 0] - lo[g, 0], H[g, 1] - lo[g, 1], H[g, 2] - lo[g, 2]) - infl
                    if k == 2:
                        side_e += sd
                        cnt_e += 1.0
                    else:
                        side_f += sd
                        cnt_f += 1.0
        ext[t, 0] = m0
        ext[t, 1] = m1
        ext[t, 2] = m2
        ext[t, 3] = x0
        ext[t, 4] = x1
        ext[t, 5] = x2
        ext[t, 6] = side_e
        ext[t, 7] = cnt_e
        ext[t, 8] = side_f
        ext[t, 9] = cnt_f
        ext[t, 10] = bad
        ext[t, 11] = bad_ids
    return lo, H, kind, grp, ri, ext, kcnt


@njit(cache=True)
def _order(kind, kcnt):  # pragma: no cover
    """Primitive ids sorted (stably) by kind."""
    nk = kcnt.shape[1]
    pos = np.zeros(nk, dtype=np.int64)
    for k in range(nk - 1):
        pos[k + 1] = pos[k] + kcnt[:, k].sum()
    order = np.empty(kind.size, dtype=np.int32)
    for g in range(kind.size):
        k = kind[g]
        order[pos[k]] = g
        pos[k] += 1
    return order


@njit(cache=True, parallel=True)
def _cells(lo, H, order, org, invh, dims, nt):  # pragma: no cover
    """First/last cell per axis of each primitive's interval [lo, H], clipped to the grid
    (cmin[g, 0] = -1: wholly outside), and entry counts per cell for each chunk of ``order``."""
    n = lo.shape[0]
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
    cmin = np.empty((n, 3), dtype=np.int32)
    cmax = np.empty((n, 3), dtype=np.int32)
    nc = dims[0] * nyz
    cnt = np.empty((nt, nc), dtype=np.int64)
    for t in prange(nt):
        for c in range(nc):
            cnt[t, c] = 0
        for p in range(t * n // nt, (t + 1) * n // nt):
            g = order[p]
            out = False
            for a in range(3):
                top = dims[a] - 1.0
                c0 = np.floor((lo[g, a] - org[a]) * invh)
                c1 = np.floor((H[g, a] - org[a]) * invh)
                if not (c1 >= 0.0 and c0 <= top):  # also catches NaN
                    out = True
                cmin[g, a] = np.int32(min(max(c0, 0.0), top))
                cmax[g, a] = np.int32(min(max(c1, 0.0), top))
            if out:
                cmin[g, 0] = -1
                continue
            x0, y0, z0 = cmin[g, 0], cmin[g, 1], cmin[g, 2]
            ex, ey, ez = cmax[g, 0] - x0, cmax[g, 1] - y0, cmax[g, 2] - z0
            base = (x0 * ny + y0) * nz + z0
            if ex <= 1 and ey <= 1 and ez <= 1:
                # at most 2 x 2 x 2 cells: one flat loop (fewer mispredicted loop exits)
                for q in range((ex + 1) * (ey + 1) * (ez + 1)):
                    dz = q & ez
                    q2 = q >> ez
                    dy = q2 & ey
                    dx = (q2 >> ey) & ex
                    cnt[t, base + dx * nyz + dy * nz + dz] += 1
            else:
                for x in range(ex + 1):
                    for y in range(ey + 1):
                        b = base + x * nyz + y * nz
                        for z in range(ez + 1):
                            cnt[t, b + z] += 1
    return cmin, cmax, cnt


@njit(cache=True)
def _offsets(cnt):  # pragma: no cover
    """Per-chunk counts -> per-chunk write positions (in place); returns the cell starts."""
    nt, nc = cnt.shape
    start = np.empty(nc + 1, dtype=np.int64)
    s = 0
    for c in range(nc):
        start[c] = s
        for t in range(nt):
            k = cnt[t, c]
            cnt[t, c] = s
            s += k
    start[nc] = s
    return start


@njit(cache=True, parallel=True)
def _fill(cmin, cmax, order, pos, dims, total):  # pragma: no cover
    nt = pos.shape[0]
    n = cmin.shape[0]
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
    items = np.empty(total, dtype=np.int32)
    for t in prange(nt):
        for p in range(t * n // nt, (t + 1) * n // nt):
            g = order[p]
            if cmin[g, 0] < 0:
                continue
            x0, y0, z0 = cmin[g, 0], cmin[g, 1], cmin[g, 2]
            ex, ey, ez = cmax[g, 0] - x0, cmax[g, 1] - y0, cmax[g, 2] - z0
            base = (x0 * ny + y0) * nz + z0
            if ex <= 1 and ey <= 1 and ez <= 1:
                for q in range((ex + 1) * (ey + 1) * (ez + 1)):
                    dz = q & ez
                    q2 = q >> ez
                    c = base + ((q2 >> ey) & ex) * nyz + (q2 & ey) * nz + dz
                    items[pos[t, c]] = g
                    pos[t, c] += 1
            else:
                for x in range(ex + 1):
                    for y in range(ey + 1):
                        b = base + x * nyz + y * nz
                        for z in range(ez + 1):
                            c = b + z
                            items[pos[t, c]] = g
                            pos[t, c] += 1
    return items


@njit(cache=True)
def _chunks(start, k, spare):  # pragma: no cover
    """At most k contiguous runs of cells of about equal work (entries^2 / 2 + entries + 1 per
    cell), the largest cell, and each run's first output row (its entries + spare rows each)."""
    nc = start.size - 1
    work = np.empty(nc + 1, dtype=np.int64)
    work[0] = 0
    big = 0
    for c in range(nc):
        m = start[c + 1] - start[c]
        big = max(big, m)
        work[c + 1] = work[c] + m * (m - 1) // 2 + m + 1
    out = np.empty(k + 1, dtype=np.int64)
    out[0] = 0
    m = 1
    c = 0
    for j in range(1, k):
        target = work[nc] * j // k
        while c < nc and work[c] < target:
            c += 1
        if c > out[m - 1]:
            out[m] = c
            m += 1
    out[m] = nc
    chunks = out[: m + 1]
    at = np.empty(m + 1, dtype=np.int64)
    at[0] = 0
    for j in range(m):
        at[j + 1] = at[j] + (start[chunks[j + 1]] - start[chunks[j]]) + spare
    return chunks, big, at


@njit(cache=True, inline="always")
def _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, mj):  # pragma: no cover
    """Branch-free test of a cell's entry j against a box (lo l, inflated hi h, mask mi): the boxes overlap, this
    cell owns the pair (the low corner of their cell ranges, bits 0-2 of the masks) and not both are in the group
    (bit 3)."""
    return (
        (box[j, 0] <= h0)
        & (l0 <= box[j, 3])
        & (box[j, 1] <= h1)
        & (l1 <= box[j, 4])
        & (box[j, 2] <= h2)
        & (l2 <= box[j, 5])
        & (((mi | mj) & 7) == 7)
        & ((mi & mj) < 8)
    )


@njit(cache=True, inline="always")
def _face_vertex_pairs(i, box, vt, msk, r0, r1, r2, r3, out_fv, pf, fv_end):  # pragma: no cover
    """Test face entry i of a cell against its vertex entries [r0, r1) and [r2, r3); returns the next output row."""
    l0, l1, l2 = box[i, 0], box[i, 1], box[i, 2]
    h0, h1, h2 = box[i, 3], box[i, 4], box[i, 5]
    mi = msk[i]
    a0, a1, a2, f = vt[i, 0], vt[i, 1], vt[i, 2], vt[i, 3]
    for run in range(2):
        ja, jb = (r0, r1) if run == 0 else (r2, r3)
        for j in range(ja, jb):
            b = vt[j, 0]
            ok = _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, msk[j]) & (a0 != b) & (a1 != b) & (a2 != b)
            if pf < fv_end:
                out_fv[pf, 0] = f
                out_fv[pf, 1] = b
            pf += ok
    return pf


@njit(cache=True, parallel=True)
def _pairs(
    chunks, dims, start, items, lo, H, kind, grp, ri, cmin, big, ee_at, fv_at, out_ee, out_fv, n_ee, n_fv
):  # pragma: no cover
    """Test the candidate pairs of every cell. Chunk k writes its ee/fv rows into
    [ee_at[k], ee_at[k + 1]) / [fv_at[k], fv_at[k + 1]) while they fit and counts all it finds in
    n_ee[k] / n_fv[k] (a count above the slice means: rerun with bigger slices)."""
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
    for k in prange(chunks.size - 1):
        box = np.empty((big, 6))
        vt = np.empty((big, 4), dtype=np.int32)  # vertex ids (-1 padded), own id
        msk = np.empty(big, dtype=np.int32)
        kc = np.empty(NUM_KINDS + 1, dtype=np.int64)
        pe = ee_at[k]
        pf = fv_at[k]
        ee_end = ee_at[k + 1]
        fv_end = fv_at[k + 1]
        for c in range(chunks[k], chunks[k + 1]):
            s = start[c]
            m = start[c + 1] - s
            if m < 2:
                continue
            cx = c // nyz
            rem = c - cx * nyz
            cy = rem // nz
            cz = rem - cy * nz
            for j in range(NUM_KINDS + 1):
                kc[j] = 0
            for j in range(m):  # entries come grouped by kind
                g = items[s + j]
                kc[kind[g] + 1] += 1
                for a in range(3):
                    box[j, a] = lo[g, a]
                    box[j, 3 + a] = H[g, a]
                for a in range(4):
                    vt[j, a] = ri[g, a]
                msk[j] = (
                    np.int32(cmin[g, 0] == cx)
                    | (np.int32(cmin[g, 1] == cy) << 1)
                    | (np.int32(cmin[g, 2] == cz) << 2)
                    | grp[g]
                )
            for j in range(NUM_KINDS):
                kc[j + 1] += kc[j]
            # class q: [kc[q], kc[q + 1]); vertices q = 0..3, edges 4..7, faces 8..11, each (dynamic, dynamic in
            # the group, static, static in the group)
            # edge-edge: a dynamic edge outside the group x every later edge; a dynamic one in the group x the
            # static edges outside it (its pairs with dynamic edges outside the group come from their loop)
            for i in range(kc[4], kc[6]):
                l0, l1, l2 = box[i, 0], box[i, 1], box[i, 2]
                h0, h1, h2 = box[i, 3], box[i, 4], box[i, 5]
                mi = msk[i]
                a0, a1, a = vt[i, 0], vt[i, 1], vt[i, 3]
                j0, j1 = (i + 1, kc[8]) if i < kc[5] else (kc[6], kc[7])
                for j in range(j0, j1):
                    b0, b1 = vt[j, 0], vt[j, 1]
                    ok = (
                        _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, msk[j])
                        & (a0 != b0)
                        & (a0 != b1)
                        & (a1 != b0)
                        & (a1 != b1)
                    )
                    if pe < ee_end:
                        b = vt[j, 3]
                        out_ee[pe, 0] = min(a, b)
                        out_ee[pe, 1] = max(a, b)
                    pe += ok
            # face-vertex: dynamic faces x all vertices, static faces x dynamic vertices; a face in the group
            # skips the vertices in the group (two runs of vertex classes)
            for q in range(8, 12):
                if q == 8:
                    r0, r1, r2, r3 = kc[0], kc[4], 0, 0
                elif q == 9:
                    r0, r1, r2, r3 = kc[0], kc[1], kc[2], kc[3]
                elif q == 10:
                    r0, r1, r2, r3 = kc[0], kc[2], 0, 0
                else:
                    r0, r1, r2, r3 = kc[0], kc[1], 0, 0
                for i in range(kc[q], kc[q + 1]):
                    pf = _face_vertex_pairs(i, box, vt, msk, r0, r1, r2, r3, out_fv, pf, fv_end)
        n_ee[k] = pe - ee_at[k]
        n_fv[k] = pf - fv_at[k]


@njit(cache=True)
def _pack(buf, at, counts):  # pragma: no cover
    total = 0
    for j in range(counts.size):
        total += counts[j]
    out = np.empty((total, 2), dtype=np.int32)
    d = 0
    for j in range(counts.size):
        s = at[j]
        for i in range(counts[j]):
            out[d, 0] = buf[s + i, 0]
            out[d, 1] = buf[s + i, 1]
            d += 1
    return out


@njit(cache=True)
def _run(  # pragma: no cover
    V0, V1, sweep, E, F, nd, still, infl, threads, scale, cells_per_prim, chunks_per_thread, spare
):
    """The whole query; returns (fv, ee, status): status 1 = non-finite coordinates, 2 = vertex id
    out of range."""
    nv = V0.shape[0]
    n = nv + E.shape[0] + F.shape[0]
    nt = max(1, min(threads, n // 2048 + 1))
    lo, H, kind, grp, ri, ext, kcnt = _boxes(V0, V1, sweep, E, F, nd, still, infl, nt)
    org = np.empty(3)
    size = np.empty(3)
    if ext[:, 11].max() > 0:
        return np.empty((0, 2), dtype=np.int32), np.empty((0, 2), dtype=np.int32), 2
    if ext[:, 10].max() > 0:
        return np.empty((0, 2), dtype=np.int32), np.empty((0, 2), dtype=np.int32), 1
    for a in range(3):
        org[a] = ext[:, a].min()
        size[a] = ext[:, 3 + a].max() - org[a]
    # cell edge from the dynamic edges' mean box side (the faces' when there are no edges)
    n_edges = ext[:, 7].sum()
    n_faces = ext[:, 9].sum()
    if n_edges > 0:
        h = infl + scale * ext[:, 6].sum() / n_edges
    elif n_faces > 0:
        h = infl + scale * ext[:, 8].sum() / n_faces
    else:
        h = infl
    if not h > 0.0:
        h = max(size.max(), 1.0)
    cap = max(64.0, cells_per_prim * n)
    dims_f = np.empty(3)
    while True:
        for a in range(3):
            dims_f[a] = np.floor(size[a] / h) + 1.0
        total = dims_f[0] * dims_f[1] * dims_f[2]
        if total <= cap:
            break
        h *= 1.01 * (total / cap) ** (1.0 / 3.0)
    dims = dims_f.astype(np.int64)

    order = _order(kind, kcnt)
    cmin, cmax, pos = _cells(lo, H, order, org, 1.0 / h, dims, nt)
    start = _offsets(pos)
    items = _fill(cmin, cmax, order, pos, dims, start[-1])
    chunks, big, at = _chunks(start, chunks_per_thread * threads if nt > 1 else 1, spare)
    nk = chunks.size - 1
    n_ee = np.empty(nk, dtype=np.int64)
    n_fv = np.empty(nk, dtype=np.int64)
    buf_ee = np.empty((at[-1], 2), dtype=np.int32)
    buf_fv = np.empty((at[-1], 2), dtype=np.int32)
    _pairs(chunks, dims, start, items, lo, H, kind, grp, ri, cmin, big, at, at, buf_ee, buf_fv, n_ee, n_fv)
    over = False
    for k in range(nk):
        over = over or n_ee[k] > at[k + 1] - at[k] or n_fv[k] > at[k + 1] - at[k]
    if not over:
        return _pack(buf_fv, at, n_fv), _pack(buf_ee, at, n_ee), 0
    # some chunk found more pairs than its slice holds: rerun with exact slices
    ee_at = np.zeros(nk + 1, dtype=np.int64)
    fv_at = np.zeros(nk + 1, dtype=np.int64)
    for k in range(nk):
        ee_at[k + 1] = ee_at[k] + n_ee[k]
        fv_at[k + 1] = fv_at[k] + n_fv[k]
    out_ee = np.empty((ee_at[nk], 2), dtype=np.int32)
    out_fv = np.empty((fv_at[nk], 2), dtype=np.int32)
    _pairs(chunks, dims, start, items, lo, H, kind, grp, ri, cmin, big, ee_at, fv_at, out_ee, out_fv, n_ee, n_fv)
    return out_fv, out_ee, 0


def _as_index(a, width: int, name: str) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.int32)
    if a.size == 0:
        return np.empty((0, width), dtype=np.int32)
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{name} must be (n, {width}) vertex ids, got shape {a.shape}")
    return a  # ids are range-checked in _boxes


def surface_candidates(
    V0: np.ndarray,
    V1: np.ndarray | None,
    edges: np.ndarray,
    faces: np.ndarray,
    inflation: float,
    num_dynamic: int,
    still: np.ndarray | None = None,
    group: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Broad-phase candidates of a 3D triangle surface.

    V0: (nv, 3) positions; V1: None (static query) or (nv, 3) end positions of a linear sweep,
    the boxes then covering both. edges (ne, 2), faces (nf, 3): vertex ids. A pair is reported
    iff on every axis ``lo_a <= hi_b + inflation and lo_b <= hi_a + inflation`` (so every pair
    closer than ``inflation`` is); pairs sharing a vertex and pairs whose vertices are all static
    (id >= num_dynamic, or marked in ``still``) are left out.

    ``still``: optional (nv,) bool, vertices that do not move in the query at hand (Dirichlet-held vertices of
    a Newton step): pairs made only of static or still vertices cannot change their distance, so the barrier
    and CCD need not see them. ``group``: optional (nv,) bool, vertices whose pairs among themselves are left out
    whether they move or not (a prescribed group, :meth:`idp.contact.model.ContactModel.leave_out_pairs_among`):
    a pair is skipped when every vertex of both primitives is in it.

    Returns (fv, ee): fv (m, 2) int32 rows [face id, vertex id]; ee (k, 2) int32 rows
    [edge a, edge b] with a < b. Each pair appears once; the row order is deterministic but not
    sorted.
    """
    V0 = np.ascontiguousarray(V0, dtype=np.float64)
    if V0.ndim != 2 or V0.shape[1] != 3:
        raise ValueError(f"V0 must be (nv, 3), got shape {V0.shape}")
    nv = V0.shape[0]
    sweep = V1 is not None
    if sweep:
        V1 = np.ascontiguousarray(V1, dtype=np.float64)
        if V1.shape != V0.shape:
            raise ValueError(f"V1 must have V0's shape {V0.shape}, got {V1.shape}")
    else:
        V1 = V0
    inflation = float(inflation)
    if not (inflation >= 0.0 and math.isfinite(inflation)):
        raise ValueError(f"inflation must be finite and >= 0, got {inflation}")
    E = _as_index(edges, 2, "edges")
    F = _as_index(faces, 3, "faces")
    nd = max(0, min(int(num_dynamic), nv))
    still_u8 = np.zeros(nv, dtype=np.uint8)  # bit 0: still, bit 1: in the group
    for bit, mask, name in ((1, still, "still"), (2, group, "group")):
        if mask is not None:
            m = np.asarray(mask)
            if m.shape != (nv,):
                raise ValueError(f"{name} must be ({nv},) per vertex, got shape {m.shape}")
            still_u8[m.astype(bool)] |= bit
    if nd == 0:  # nothing is dynamic: no pair can be reported
        for a, name in ((E, "edges"), (F, "faces")):
            if a.size and (int(a.min()) < 0 or int(a.max()) >= nv):
                raise ValueError(f"{name} reference vertices outside [0, {nv})")
        return _EMPTY.copy(), _EMPTY.copy()
    fv, ee, status = _run(
        V0,
        V1,
        sweep,
        E,
        F,
        nd,
        still_u8,
        inflation,
        numba.get_num_threads(),
        _CELL_SCALE,
        _CELLS_PER_PRIM,
        _CHUNKS_PER_THREAD,
        _SPARE_ROWS,
    )
    if status == 2:
        raise ValueError(f"edges or faces reference vertices outside [0, {nv})")
    if status:
        raise ValueError("vertex positions must be finite")
    return fv, ee
