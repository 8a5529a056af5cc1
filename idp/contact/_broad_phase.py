"""Numba broad phase for 3D triangle surfaces: face-vertex and edge-edge candidates as int arrays.

ipctk's Python bindings hand candidates back as lists of Python objects (~10 ms per 10K pairs to
turn into arrays); :func:`surface_candidates` produces the arrays directly.

Rule. Each primitive (vertex, edge, face) has the axis-aligned box [lo, hi] of its vertices (at
V0, and also at V1 for a linear sweep). A pair is reported iff, on every axis,
``lo_a <= hi_b + inflation and lo_b <= hi_a + inflation``, evaluated literally (``hi + inflation``
is rounded once and stored), so a brute force implementing the same expression gets the same set.
A sweep that moves some vertex further than a grid cell also drops the pairs that fail the moving-box
test ("Long sweeps" below), which no pair coming within the inflation fails.
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

Long sweeps. A Newton direction of the mannequin's repair carries the kicking leg 0.1-0.3 (30 d-hat) in one
sweep: its primitives' swept boxes overlap everything the leg passes and each other (4 M box pairs, 0.4-0.65 s per
query and as much again in CCD, 10 such sweeps in 5 frames), and the cell that suits them lumps the still body into
cells of 15,000 entries. Two changes, both only for sweeps that move some vertex further than a cell:
- the moving-box test: primitive g lies at every t of the sweep in [lo0 + t dmin, hi0 + t dmax] (its start box and
  its vertices' least and largest displacement per axis); a pair is kept only if those boxes (inflated) overlap on
  every axis at one common t, an interval test on six linear conditions (pairs overlapping at t = 0 pass at once).
  It is a refinement of the swept-box test, so nothing that comes within the inflation is dropped; primitives that
  move together keep only their near pairs (4 M -> 0.5 M on the kick).
- long and short primitives: a primitive whose sweep box reaches more than _LONG_REACH start-box cells beyond its
  start box is long. Short ones pair among themselves in the grid of their own (swept) boxes, long ones among
  themselves in a grid of theirs, and each long one is tested against the short ones binned in the fine grid over
  the cells its box covers (the same low-corner ownership, so no duplicates). The union is exactly the one-grid set
  (tested at several thresholds). Kick frames 67-71: 0.39-0.65 s -> 0.25-0.29 s per long query, CCD 3.6 -> 1.4 s.
Co-moving frame (``co_moving=True``, what the contact model asks for its sweeps). Distances between two points moving
linearly are unchanged when one common velocity is taken off both, so a sweep's pairs can be looked for in the frame
that moves with the sweep's per-axis median displacement c (V1 - c; static and still vertices then move by -c, and
still no pair of theirs changes its distance, so leaving such pairs out stays right). A Newton direction of a scene
falling under gravity moves every body by nearly the same step: in the plain frame each primitive's sweep box is that
step long (the co-moving bundle of Fig. 22's early iterates, 207K surface vertices falling 3e-3 against d-hat 1e-4),
in the co-moving one only its own deformation's length. The inflation grows by a few ulps of the coordinates to
cover the rounding of V1 - c, so every pair within the inflation is still reported. Measured (2-core AMD EPYC VM, one
thread, the plain and co-moving runs side by side): Fig. 21's eight dumplings falling (steps 1-9, 133K vertices)
took 12-26 s of contact building a step in the plain frame, 0.7-1.1 s in the co-moving one (the steps 25-52 s ->
10-23 s, the same iterates); Fig. 22's slowest sweeps of step 1 1.9-6.8 s -> 1.4-5.7 s (the same pairs but for 1-9
face-vertex pairs that never come near each other: its long primitives, 15 % of them, mostly one rhododendron swinging,
and the long-long pass stays), the step itself 300 -> 297 s.
Tried and dropped for long sweeps: splitting the sweep into time slabs (each long primitive binned once per slab,
a pair reported in its first slab): co-moving primitives still meet in every slab, so the box tests stay about the
same (0.2-0.4 s) while the bookkeeping grows; a finer or coarser single grid (0.32-1.9 s).

Parallelism: boxes, binning and the cell loop are prange loops over a few work-balanced chunks
(numba's thread count is left alone; no np.zeros in the parallel functions, each would be one more
parallel region, ~50 us of worker wake-up under OMP_WAIT_POLICY=PASSIVE). Each chunk of cells
writes into its own slice of the output buffers; a chunk that finds more pairs than its slice
holds (the slice holds as many rows as the chunk has cell entries, plus 256) makes the pass rerun
with exact slices. Output order is deterministic (by cell, then by position in the cell) but not
sorted. The bodies of most prange loops are plain functions (``_pairs_chunk`` and the like, called with an int64
chunk index so one compiled version serves both numba's typing and its parallel loop): numba's parallel passes over
the inlined cell loop took 11.6 s of the first run's compilation, over a call 1.4 s; the whole query compiles in
26 instead of 32 s on the 2-core Intel VM, and runs at the same speed (cat frames, 2 threads: 9.0-9.5 ms static,
10.5-10.9 ms swept, interleaved A/B in one process). ``_cells`` and ``_cross`` keep their loops inline: as
functions they ran the long-sweep query 5-8 % slower.

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

from idp._leaf import leaf_njit

# Cell edge = _CELL_SCALE * (mean largest box side of the dynamic edges) + inflation
# (bunny_3376, 2 threads: 0.8 -> 2.50 ms, 1.0 -> 2.31, 1.2 -> 2.18, 1.4 -> 2.20, 1.7 -> 2.46, 2.0 -> 3.83).
_CELL_SCALE = 1.2
# The grid is dense: never more cells than this many per primitive (the cell grows instead).
_CELLS_PER_PRIM = 4
_CHUNKS_PER_THREAD = 4
# Output rows reserved per chunk of cells: its number of cell entries plus this.
_SPARE_ROWS = 256
# A sweep primitive is "long" when its sweep box reaches this many start-box cells further than its start box; the
# long ones' grid has cells of _LONG_SCALE x their mean box side + inflation.
_LONG_REACH = 2.0
_LONG_SCALE = 1.2
# Pairs of a sweep are also put to the moving-box test once some vertex moves further than this many cells (below,
# swept boxes are nearly as tight and the test costs more than it saves).
_MOVING_REACH = 1.0

_EMPTY = np.empty((0, 2), dtype=np.int32)

# Primitive classes: 4 x type (vertex, edge, face) + (dynamic outside the group, dynamic in it, static outside,
# static in it).
NUM_KINDS = 12


@leaf_njit(inline="always")
def _sweep_reach(mv, g):  # pragma: no cover
    """How much longer than its start box primitive g's sweep box is on its worst axis."""
    r = 0.0
    for a in range(3):
        r = max(r, max(mv[g, 9 + a], 0.0) - min(mv[g, 6 + a], 0.0))
    return r


@leaf_njit()
def _boxes_chunk(t, nt, V0, V1, sweep, E, F, nd, still, infl, lo, H, kind, grp, ri, ext):  # pragma: no cover
    """Chunk t of nt of :func:`_boxes` (plain: see :func:`_pairs_chunk`)."""
    nv = V0.shape[0]
    ne = E.shape[0]
    n = nv + ne + F.shape[0]
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
    disp = 0.0
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
        if d:
            m0 = min(m0, lo[g, 0])
            m1 = min(m1, lo[g, 1])
            m2 = min(m2, lo[g, 2])
            x0 = max(x0, H[g, 0])
            x1 = max(x1, H[g, 1])
            x2 = max(x2, H[g, 2])
            if sweep and k == 1:
                for a in range(3):
                    disp = max(disp, abs(V1[g, a] - V0[g, a]))
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
    ext[t, 12] = disp


@njit(cache=True, parallel=True)
def _boxes(V0, V1, sweep, E, F, nd, still, infl, nt):  # pragma: no cover
    """Per primitive g (vertices, then edges, then faces): lo, H = hi + infl, kind = 4 type + class (type 0/1/2
    vertex/edge/face; class 0 dynamic outside the group, 1 dynamic in it, 2 static outside, 3 static in it; a
    vertex is dynamic when its id < nd and bit 0 of ``still`` (still) is 0 for it, an edge or face when one of its
    vertices is), grp[g] = 8 when bit 1 of ``still`` (in the group whose pairs among themselves are skipped) is set
    for every vertex of g, else 0; ri = (vertex ids, padded with -1; own id).
    ext[t] = this chunk's (min dynamic lo (3), max dynamic H (3), sum of the dynamic edges'
    largest box side, their count, the same for the dynamic faces, 1 if it saw a non-finite
    coordinate, 1 if it saw a vertex id outside [0, nv), the largest displacement component of a dynamic vertex);
    """
    nv = V0.shape[0]
    ne = E.shape[0]
    n = nv + ne + F.shape[0]
    lo = np.empty((n, 3))
    H = np.empty((n, 3))
    kind = np.empty(n, dtype=np.int8)
    grp = np.empty(n, dtype=np.int32)
    ri = np.empty((n, 4), dtype=np.int32)
    ext = np.empty((nt, 13))
    for t in prange(nt):
        _boxes_chunk(np.int64(t), nt, V0, V1, sweep, E, F, nd, still, infl, lo, H, kind, grp, ri, ext)
    return lo, H, kind, grp, ri, ext


@leaf_njit()
def _moving_boxes_chunk(t, nt, V0, V1, ri, kind, infl, mv, stat):  # pragma: no cover
    """Chunk t of nt of :func:`_moving_boxes` (plain: see :func:`_pairs_chunk`)."""
    n = ri.shape[0]
    side0 = 0.0
    reach = 0.0
    for g in range(t * n // nt, (t + 1) * n // nt):
        k = kind[g] // 4 + 1
        for a in range(3):
            l0 = np.inf
            h0 = -np.inf
            dn = np.inf
            dx = -np.inf
            for j in range(k):
                v = ri[g, j]
                x = V0[v, a]
                l0 = min(l0, x)
                h0 = max(h0, x)
                x = V1[v, a] - x
                dn = min(dn, x)
                dx = max(dx, x)
            mv[g, a] = l0
            mv[g, 3 + a] = h0 + infl
            mv[g, 6 + a] = dn
            mv[g, 9 + a] = dx
        if kind[g] % 4 < 2:  # dynamic
            reach = max(reach, _sweep_reach(mv, g))
            if k == 2:
                side0 += max(mv[g, 3] - mv[g, 0], mv[g, 4] - mv[g, 1], mv[g, 5] - mv[g, 2]) - infl
    stat[t, 0] = side0
    stat[t, 1] = reach


@njit(cache=True, parallel=True)
def _moving_boxes(V0, V1, ri, kind, infl, nt):  # pragma: no cover
    """Per primitive of a sweep its moving box, which holds it at every t of the sweep: rows lo0 (3), hi0 + infl
    (3) at V0 and the least and largest displacement of its vertices per axis (dmin (3), dmax (3)). Also per chunk
    (stat[t]): the sum of the dynamic edges' largest start-box side and the largest :func:`_sweep_reach` of a
    dynamic primitive."""
    n = ri.shape[0]
    mv = np.empty((n, 12))
    stat = np.empty((nt, 2))
    for t in prange(nt):
        _moving_boxes_chunk(np.int64(t), nt, V0, V1, ri, kind, infl, mv, stat)
    return mv, stat


@njit(cache=True, parallel=True)
def _cells(lo, H, order, org, invh, dims, nt):  # pragma: no cover
    """First/last cell per axis of each primitive's interval [lo, H], clipped to the grid
    (cmin[g, 0] = -1: wholly outside), and entry counts per cell for each chunk of ``order``."""
    n = order.size
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
    cmin = np.empty((lo.shape[0], 3), dtype=np.int32)  # rows of the primitives in order only
    cmax = np.empty((lo.shape[0], 3), dtype=np.int32)
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


@leaf_njit()
def _fill_chunk(t, nt, cmin, cmax, order, pos, dims, items):  # pragma: no cover
    """Chunk t of nt of :func:`_fill` (plain: see :func:`_pairs_chunk`)."""
    n = order.size
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
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


@njit(cache=True, parallel=True)
def _fill(cmin, cmax, order, pos, dims, total):  # pragma: no cover
    nt = pos.shape[0]
    items = np.empty(total, dtype=np.int32)
    for t in prange(nt):
        _fill_chunk(np.int64(t), nt, cmin, cmax, order, pos, dims, items)
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


@leaf_njit(inline="always")
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


@leaf_njit(inline="always")
def _edge_pair(box, vt, msk, j, l0, l1, l2, h0, h1, h2, mi, a0, a1):  # pragma: no cover
    """Branch-free: the edge with box (l, h), mask mi and vertices a0, a1 and the cell's edge entry j meet
    (:func:`_boxes_meet`) and share no vertex."""
    b0, b1 = vt[j, 0], vt[j, 1]
    return _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, msk[j]) & (a0 != b0) & (a0 != b1) & (a1 != b0) & (a1 != b1)


@leaf_njit(inline="always")
def _moving_boxes_meet(mb, i, j, pad):  # pragma: no cover
    """Whether rows i and j of ``mb`` (a cell's scratch copy, or the moving boxes themselves) can overlap (inflated)
    at one time t in [0, 1] of the sweep: the moving boxes [lo0 + t dmin, hi0 + infl + t dmax] (``mb`` rows: lo0,
    hi0 + infl, dmin, dmax per axis) must overlap on every axis at the same t. Each of the six conditions is linear
    in t; they bound an interval of t, which must not be empty. ``pad`` widens every condition (a margin far above
    the rounding of the divisions)."""
    if (
        mb[i, 0] <= mb[j, 3] + pad
        and mb[j, 0] <= mb[i, 3] + pad
        and mb[i, 1] <= mb[j, 4] + pad
        and mb[j, 1] <= mb[i, 4] + pad
        and mb[i, 2] <= mb[j, 5] + pad
        and mb[j, 2] <= mb[i, 5] + pad
    ):
        return True  # they overlap at t = 0 (the common case of short sweeps: no divisions)
    tlo = 0.0
    thi = 1.0
    for a in range(3):
        for q in range(2):
            u, w = (i, j) if q == 0 else (j, i)
            # lo_u(t) <= hi_w(t) + infl:  t (dmin_u - dmax_w) <= hi0_w + infl - lo0_u
            c = mb[u, 6 + a] - mb[w, 9 + a]
            r = mb[w, 3 + a] - mb[u, a] + pad
            if c > 0.0:
                thi = min(thi, r / c)
            elif c < 0.0:
                tlo = max(tlo, r / c)
            elif r < 0.0:
                return False
    return tlo <= thi


@leaf_njit(inline="always")
def _face_vertex_pairs(i, box, vt, msk, r0, r1, r2, r3, out_fv, pf, fv_end, mb, moving, pad):  # pragma: no cover
    """Test face entry i of a cell against its vertex entries [r0, r1) and [r2, r3); returns the next output row.
    ``moving``: a sweep, whose pairs must also pass :func:`_moving_boxes_meet`."""
    l0, l1, l2 = box[i, 0], box[i, 1], box[i, 2]
    h0, h1, h2 = box[i, 3], box[i, 4], box[i, 5]
    mi = msk[i]
    a0, a1, a2, f = vt[i, 0], vt[i, 1], vt[i, 2], vt[i, 3]
    for run in range(2):
        ja, jb = (r0, r1) if run == 0 else (r2, r3)
        if moving:  # (two loops: the plain one stays branch-free)
            for j in range(ja, jb):
                b = vt[j, 0]
                ok = _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, msk[j]) & (a0 != b) & (a1 != b) & (a2 != b)
                if ok:
                    ok = _moving_boxes_meet(mb, i, j, pad)
                if pf < fv_end:
                    out_fv[pf, 0] = f
                    out_fv[pf, 1] = b
                pf += ok
        else:
            for j in range(ja, jb):
                b = vt[j, 0]
                ok = _boxes_meet(box, j, l0, l1, l2, h0, h1, h2, mi, msk[j]) & (a0 != b) & (a1 != b) & (a2 != b)
                if pf < fv_end:
                    out_fv[pf, 0] = f
                    out_fv[pf, 1] = b
                pf += ok
    return pf


@njit(cache=True)
def _pairs_chunk(
    k, chunks, dims, start, items, lo, H, kind, grp, ri, mv, pad, cmin, big, ee_at, fv_at, out_ee, out_fv, n_ee, n_fv
):  # pragma: no cover
    """Chunk k of :func:`_pairs` (a plain function: numba's parallel passes over this body, inlined helpers and
    all, took 11.6 of the broad phase's 32 s of first-run compilation; called from the prange loop it costs ≈ 1.5 s)."""
    ny, nz = dims[1], dims[2]
    nyz = ny * nz
    box = np.empty((big, 6))
    vt = np.empty((big, 4), dtype=np.int32)  # vertex ids (-1 padded), own id
    msk = np.empty(big, dtype=np.int32)
    moving = mv.shape[0] > 0
    mb = np.empty((big if moving else 0, 12))
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
            if moving:
                for a in range(12):
                    mb[j, a] = mv[g, a]
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
            if moving:  # (two loops: the plain one stays branch-free)
                for j in range(j0, j1):
                    ok = _edge_pair(box, vt, msk, j, l0, l1, l2, h0, h1, h2, mi, a0, a1)
                    if ok:
                        ok = _moving_boxes_meet(mb, i, j, pad)
                    if pe < ee_end:
                        b = vt[j, 3]
                        out_ee[pe, 0] = min(a, b)
                        out_ee[pe, 1] = max(a, b)
                    pe += ok
            else:
                for j in range(j0, j1):
                    ok = _edge_pair(box, vt, msk, j, l0, l1, l2, h0, h1, h2, mi, a0, a1)
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
                pf = _face_vertex_pairs(i, box, vt, msk, r0, r1, r2, r3, out_fv, pf, fv_end, mb, moving, pad)
    n_ee[k] = pe - ee_at[k]
    n_fv[k] = pf - fv_at[k]


@njit(cache=True, parallel=True)
def _pairs(
    chunks,
    dims,
    start,
    items,
    lo,
    H,
    kind,
    grp,
    ri,
    mv,
    pad,
    cmin,
    big,
    ee_at,
    fv_at,
    out_ee,
    out_fv,
    n_ee,
    n_fv,
):  # pragma: no cover
    """Test the candidate pairs of every cell. Chunk k writes its ee/fv rows into
    [ee_at[k], ee_at[k + 1]) / [fv_at[k], fv_at[k + 1]) while they fit and counts all it finds in
    n_ee[k] / n_fv[k] (a count above the slice means: rerun with bigger slices)."""
    for k in prange(chunks.size - 1):
        _pairs_chunk(
            np.int64(k),
            chunks,
            dims,
            start,
            items,
            lo,
            H,
            kind,
            grp,
            ri,
            mv,
            pad,
            cmin,
            big,
            ee_at,
            fv_at,
            out_ee,
            out_fv,
            n_ee,
            n_fv,
        )


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
def _order(kind, sel, want):  # pragma: no cover
    """Ids of the primitives with ``sel == want``, sorted (stably) by kind (a counting sort)."""
    pos = np.zeros(NUM_KINDS + 1, dtype=np.int64)
    for g in range(kind.size):
        if sel[g] == want:
            pos[kind[g] + 1] += 1
    for k in range(NUM_KINDS):
        pos[k + 1] += pos[k]
    order = np.empty(pos[NUM_KINDS], dtype=np.int32)
    for g in range(kind.size):
        if sel[g] == want:
            k = kind[g]
            order[pos[k]] = g
            pos[k] += 1
    return order


@njit(cache=True)
def _grid_size(size, h, cap):  # pragma: no cover
    """Cells per axis for cell edge h over a region of ``size``, the edge grown until at most ``cap`` cells."""
    dims_f = np.empty(3)
    while True:
        for a in range(3):
            dims_f[a] = np.floor(size[a] / h) + 1.0
        total = dims_f[0] * dims_f[1] * dims_f[2]
        if total <= cap:
            break
        h *= 1.01 * (total / cap) ** (1.0 / 3.0)
    return dims_f.astype(np.int64), h


@njit(cache=True)
def _grid_pairs(prims, order, org, h, grid):  # pragma: no cover
    """(fv, ee) of the primitives in ``order`` among themselves: a uniform grid of edge about h, every cell's
    pairs tested by :func:`_pairs`. ``prims`` = (lo, H, kind, grp, ri, mv, pad) of every primitive, ``grid`` =
    (cells_per_prim, size, nt, threads, chunks_per_thread, spare)."""
    lo, H, kind, grp, ri, mv, pad = prims
    cells_per_prim, size, nt, threads, chunks_per_thread, spare = grid
    dims, h = _grid_size(size, h, max(64.0, cells_per_prim * order.size))
    cmin, cmax, pos = _cells(lo, H, order, org, 1.0 / h, dims, nt)
    start = _offsets(pos)
    items = _fill(cmin, cmax, order, pos, dims, start[-1])
    chunks, big, at = _chunks(start, chunks_per_thread * threads if nt > 1 else 1, spare)
    nk = chunks.size - 1
    n_e = np.empty(nk, dtype=np.int64)
    n_f = np.empty(nk, dtype=np.int64)
    e_at = at
    f_at = at
    for _attempt in range(2):
        out_e = np.empty((e_at[nk], 2), dtype=np.int32)
        out_f = np.empty((f_at[nk], 2), dtype=np.int32)
        _pairs(chunks, dims, start, items, lo, H, kind, grp, ri, mv, pad, cmin, big, e_at, f_at, out_e, out_f, n_e, n_f)
        over = False
        for k in range(nk):
            over = over or n_e[k] > e_at[k + 1] - e_at[k] or n_f[k] > f_at[k + 1] - f_at[k]
        if not over:
            break
        # some chunk found more pairs than its slice holds: rerun with exact slices
        e_at = np.zeros(nk + 1, dtype=np.int64)
        f_at = np.zeros(nk + 1, dtype=np.int64)
        for k in range(nk):
            e_at[k + 1] = e_at[k] + n_e[k]
            f_at[k + 1] = f_at[k] + n_f[k]
    return _pack(out_f, f_at, n_f), _pack(out_e, e_at, n_e)


@leaf_njit(inline="always")
def _cross_pair(lo, H, kind, ri, mv, pad, cmin_l, cmin_s, g, s, cx, cy, cz):  # pragma: no cover
    """0 (no pair), 1 (face-vertex) or 2 (edge-edge) for long primitive g and short primitive s met in cell
    (cx, cy, cz): the pair's kinds match, not both are static, not both in the group, they share no vertex, their
    inflated boxes overlap, this cell is the low corner of their cell ranges' intersection, and their moving
    boxes meet (:func:`_moving_boxes_meet`)."""
    tg = kind[g] // 4
    ts = kind[s] // 4
    if tg == 1:
        if ts != 1:
            return 0
        res = 2
    elif tg + ts != 2:  # face x vertex, or vertex x face
        return 0
    else:
        res = 1
    cg = kind[g] % 4
    cs = kind[s] % 4
    if cg >= 2 and cs >= 2:  # both static
        return 0
    if (cg & 1) == 1 and (cs & 1) == 1:  # both in the group
        return 0
    if not (max(cmin_l[g, 0], cmin_s[s, 0]) == cx and max(cmin_l[g, 1], cmin_s[s, 1]) == cy):
        return 0
    if max(cmin_l[g, 2], cmin_s[s, 2]) != cz:
        return 0
    for a in range(3):
        if not (lo[s, a] <= H[g, a] and lo[g, a] <= H[s, a]):
            return 0
    for p in range(tg + 1):
        for q in range(ts + 1):
            if ri[g, p] == ri[s, q]:
                return 0
    if mv.shape[0] > 0 and not _moving_boxes_meet(mv, g, s, pad):
        return 0
    return res


@njit(cache=True, parallel=True)
def _cross(
    lo, H, kind, ri, mv, pad, long_ids, cmin_l, cmax_l, cmin_s, start, items, dims, nt, n_fv, n_ee, out_fv, out_ee, at
):  # pragma: no cover
    """Pairs of a long primitive (``long_ids``, cell ranges cmin_l/cmax_l) with the short ones binned in the same
    grid (``start``/``items``, cell ranges cmin_s). Chunk t of the long primitives writes into rows
    [at[t], at[t + 1]) of out_fv / out_ee while they fit and counts all it finds (n_fv[t], n_ee[t])."""
    ny, nz = dims[1], dims[2]
    m = long_ids.size
    for t in prange(nt):
        pf = at[t]
        pe = at[t]
        end = at[t + 1]
        for p in range(t * m // nt, (t + 1) * m // nt):
            g = long_ids[p]
            if cmin_l[g, 0] < 0:
                continue
            for x in range(cmin_l[g, 0], cmax_l[g, 0] + 1):
                for y in range(cmin_l[g, 1], cmax_l[g, 1] + 1):
                    for z in range(cmin_l[g, 2], cmax_l[g, 2] + 1):
                        c = (x * ny + y) * nz + z
                        for e in range(start[c], start[c + 1]):
                            s = items[e]
                            kindpair = _cross_pair(lo, H, kind, ri, mv, pad, cmin_l, cmin_s, g, s, x, y, z)
                            if kindpair == 1:
                                if pf < end:
                                    if kind[g] >= 8:
                                        out_fv[pf, 0] = ri[g, 3]
                                        out_fv[pf, 1] = ri[s, 0]
                                    else:
                                        out_fv[pf, 0] = ri[s, 3]
                                        out_fv[pf, 1] = ri[g, 0]
                                pf += 1
                            elif kindpair == 2:
                                if pe < end:
                                    a = ri[g, 3]
                                    b = ri[s, 3]
                                    out_ee[pe, 0] = min(a, b)
                                    out_ee[pe, 1] = max(a, b)
                                pe += 1
        n_fv[t] = pf - at[t]
        n_ee[t] = pe - at[t]


@njit(cache=True)
def _cross_grid(lo, H, kind, ri, mv, pad, order_l, order_s, org, h, cells_per_prim, size, nt):  # pragma: no cover
    """(fv, ee) pairs of every primitive in ``order_l`` with every one in ``order_s``: the latter binned in a grid of
    edge about h, each of the former tested against the cells its box covers (:func:`_cross`)."""
    dims, h = _grid_size(size, h, max(64.0, cells_per_prim * (order_l.size + order_s.size)))
    one = np.int64(1)  # not a literal 1: numba would compile another _cells (a parallel one) for it
    cmin_l, cmax_l, _ = _cells(lo, H, order_l, org, 1.0 / h, dims, one)
    cmin_s, cmax_s, pos = _cells(lo, H, order_s, org, 1.0 / h, dims, one)
    start = _offsets(pos)
    items = _fill(cmin_s, cmax_s, order_s, pos, dims, start[-1])
    ntc = max(1, min(nt * 8, order_l.size))
    n_fv = np.empty(ntc, dtype=np.int64)
    n_ee = np.empty(ntc, dtype=np.int64)
    at = np.empty(ntc + 1, dtype=np.int64)
    m = order_l.size
    at[0] = 0
    for t in range(ntc):
        at[t + 1] = at[t] + 16 * ((t + 1) * m // ntc - t * m // ntc) + 256
    for _attempt in range(2):
        out_fv = np.empty((at[ntc], 2), dtype=np.int32)
        out_ee = np.empty((at[ntc], 2), dtype=np.int32)
        _cross(
            lo,
            H,
            kind,
            ri,
            mv,
            pad,
            order_l,
            cmin_l,
            cmax_l,
            cmin_s,
            start,
            items,
            dims,
            ntc,
            n_fv,
            n_ee,
            out_fv,
            out_ee,
            at,
        )
        over = False
        for t in range(ntc):
            over = over or n_fv[t] > at[t + 1] - at[t] or n_ee[t] > at[t + 1] - at[t]
        if not over:
            break
        for t in range(ntc):  # rerun with slices that hold what each chunk found
            at[t + 1] = at[t] + max(n_fv[t], n_ee[t])
    return _pack(out_fv, at, n_fv), _pack(out_ee, at, n_ee)


@njit(cache=True)
def _concat(a, b, c):  # pragma: no cover
    """The rows of a, b and c in one array (copied by loops: numba's slice assignment brings its shape-mismatch
    error message along, 3 s of first-run compilation)."""
    out = np.empty((a.shape[0] + b.shape[0] + c.shape[0], 2), dtype=np.int32)
    r = 0
    for part in (a, b, c):
        for i in range(part.shape[0]):
            out[r, 0] = part[i, 0]
            out[r, 1] = part[i, 1]
            r += 1
    return out


@njit(cache=True)
def _run(  # pragma: no cover
    V0,
    V1,
    sweep,
    E,
    F,
    nd,
    still,
    infl,
    threads,
    scale,
    cells_per_prim,
    chunks_per_thread,
    spare,
    long_reach,
    long_scale,
    moving_reach,
):
    """The whole query; returns (fv, ee, status): status 1 = non-finite coordinates, 2 = vertex id
    out of range."""
    nv = V0.shape[0]
    n = nv + E.shape[0] + F.shape[0]
    nt = max(1, min(threads, n // 2048 + 1))
    lo, H, kind, grp, ri, ext = _boxes(V0, V1, sweep, E, F, nd, still, infl, nt)
    org = np.empty(3)
    size = np.empty(3)
    if ext[:, 11].max() > 0:
        return np.empty((0, 2), dtype=np.int32), np.empty((0, 2), dtype=np.int32), 2
    if ext[:, 10].max() > 0:
        return np.empty((0, 2), dtype=np.int32), np.empty((0, 2), dtype=np.int32), 1
    for a in range(3):
        org[a] = ext[:, a].min()
        size[a] = ext[:, 3 + a].max() - org[a]
    # the moving-box test's margin: far above the rounding of its terms (coordinates and inflation)
    pad = 1e-9 * (max(np.abs(org).max(), np.abs(org + size).max()) + infl)
    n_edges = ext[:, 7].sum()
    n_faces = ext[:, 9].sum()
    # cell edge from the dynamic edges' mean box side (the faces' when there are no edges)
    if n_edges > 0:
        h = infl + scale * ext[:, 6].sum() / n_edges
    elif n_faces > 0:
        h = infl + scale * ext[:, 8].sum() / n_faces
    else:
        h = infl
    if not h > 0.0:
        h = max(size.max(), 1.0)
    # A sweep that moves some vertex further than about a cell: its pairs must also pass the moving-box test, which
    # drops the swept-box pairs of primitives that are never near each other at one time. When some primitives'
    # sweep boxes reach much further than the cell their start boxes call for, those ("long") pair among themselves
    # in a coarse grid and with the others ("short") by a cross pass over a grid of the short ones, while the short
    # ones pair among themselves in the fine grid of their own boxes.
    mv = np.empty((0, 12))
    split = False
    h0 = h
    grid = (cells_per_prim, size, nt, threads, chunks_per_thread, spare)
    if sweep and n_edges > 0 and ext[:, 12].max() > moving_reach * h:
        mv, stat = _moving_boxes(V0, V1, ri, kind, infl, nt)
        h0 = infl + scale * stat[:, 0].sum() / n_edges
        split = h0 > 0.0 and stat[:, 1].max() > long_reach * h0
    prims = (lo, H, kind, grp, ri, mv, pad)
    if split:
        is_long = np.empty(n, dtype=np.int8)
        side_s = 0.0
        cnt_s = 0.0
        side_l = 0.0
        cnt_l = 0.0
        for g in range(n):
            lg = kind[g] % 4 < 2 and _sweep_reach(mv, g) > long_reach * h0
            is_long[g] = 1 if lg else 0
            if kind[g] // 4 == 1 and kind[g] % 4 < 2:
                sd = max(H[g, 0] - lo[g, 0], H[g, 1] - lo[g, 1], H[g, 2] - lo[g, 2]) - infl
                if lg:
                    side_l += sd
                    cnt_l += 1.0
                else:
                    side_s += sd
                    cnt_s += 1.0
        order_s = _order(kind, is_long, np.int64(0))  # np.int64, not literals: one _order compiled, not two
        order_l = _order(kind, is_long, np.int64(1))
        h_s = infl + scale * side_s / cnt_s if cnt_s > 0 else h0
        h_l = infl + long_scale * side_l / cnt_l if cnt_l > 0 else h0
        fv_s, ee_s = _grid_pairs(prims, order_s, org, h_s, grid)
        fv_l, ee_l = _grid_pairs(prims, order_l, org, h_l, grid)
        fv_x, ee_x = _cross_grid(lo, H, kind, ri, mv, pad, order_l, order_s, org, h_s, cells_per_prim, size, threads)
        return _concat(fv_s, fv_l, fv_x), _concat(ee_s, ee_l, ee_x), 0
    order = _order(kind, np.zeros(n, dtype=np.int8), np.int64(0))
    fv, ee = _grid_pairs(prims, order, org, h, grid)
    return fv, ee, 0


def _co_moving(V0: np.ndarray, V1: np.ndarray, inflation: float) -> tuple[np.ndarray, float]:
    """End positions of the sweep V0 -> V1 in the frame moving with its per-axis median displacement c, and the
    inflation grown by the rounding of V1 - c (a few ulps of the largest coordinate). V1 itself when c = 0 or when
    a coordinate is not finite (the query reports that)."""
    c = np.median(V1 - V0, axis=0)
    if not np.all(np.isfinite(c)) or not np.any(c):
        return V1, inflation
    V1c = V1 - c
    scale = max(float(np.abs(V0).max()), float(np.abs(V1).max()), float(np.abs(c).max()))
    if not math.isfinite(scale):
        return V1, inflation
    # |V1 - c| <= 2 scale, so each shifted coordinate is off by at most eps * 2 scale, and on each axis the gap
    # between two vertices at any t of the sweep by twice that: 8 eps * scale
    return V1c, inflation + 8.0 * np.finfo(float).eps * scale


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
    *,
    co_moving: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Broad-phase candidates of a 3D triangle surface.

    V0: (nv, 3) positions; V1: None (static query) or (nv, 3) end positions of a linear sweep,
    the boxes then covering both. edges (ne, 2), faces (nf, 3): vertex ids. A pair is reported
    iff on every axis ``lo_a <= hi_b + inflation and lo_b <= hi_a + inflation`` (so every pair
    closer than ``inflation`` is) and, for a sweep moving some vertex further than a grid cell, the two
    primitives' moving boxes overlap at one common time (the module docstring); pairs sharing a vertex and pairs
    whose vertices are all static (id >= num_dynamic, or marked in ``still``) are left out.

    ``still``: optional (nv,) bool, vertices that do not move in the query at hand (Dirichlet-held vertices of
    a Newton step): pairs made only of static or still vertices cannot change their distance, so the barrier
    and CCD need not see them. ``group``: optional (nv,) bool, vertices whose pairs among themselves are left out
    whether they move or not (a prescribed group, :meth:`idp.contact.model.ContactModel.leave_out_pairs_among`):
    a pair is skipped when every vertex of both primitives is in it.

    ``co_moving`` (sweeps only): the boxes are those of the sweep seen from the frame moving with the median
    displacement of its vertices (module docstring, "Co-moving frame"), inflated by a few more ulps; every pair
    that comes within ``inflation`` is reported as before, and the pairs that only move together are not looked at.

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
    if sweep and co_moving and nv:
        V1, inflation = _co_moving(V0, V1, inflation)
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
        _LONG_REACH,
        _LONG_SCALE,
        _MOVING_REACH,
    )
    if status == 2:
        raise ValueError(f"edges or faces reference vertices outside [0, {nv})")
    if status:
        raise ValueError("vertex positions must be finite")
    return fv, ee
