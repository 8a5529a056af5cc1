"""IPC barrier on arrays: collision set, value, gradient and projected Hessian blocks, compiled with numba.

Why not ipctk's: its Python bindings hand collisions and candidates over only as lists of Python
objects (≈ 1.4 µs per collision to read back), and its Hessian is a scipy matrix assembled from
projected 12×12 blocks that include the DOFs of static obstacles. Measured at bunny_700, 3,736
collisions: 19 ms per Hessian (9.7 ms without the projection), the largest cost after the sparse
solve. Here the collision set stays in arrays, each block is projected after removing the vertices
that are not optimised (a bunny vertex against a box face: 3×3 instead of 12×12), and the blocks go
straight into the Newton matrix's pattern.

The energy is ipctk's ``BarrierPotential`` for the IPC collision set (``NormalCollisions``, no area
weighting, d_min = 0): κ Σ m_k(x) b(d_k(x), d̂²) over unique collisions, d squared distances,
b(d) = −(d − d̂²)² ln(d / d̂²), m the edge-edge mollifier. The collision set is classified the same way
(tests compare value, gradient and unprojected Hessian against ipctk):
- face–vertex candidates within d̂: point–plane (FV) when the closest point is inside the triangle,
  else the edge (EV) or vertex (VV) it is on;
- edge–edge candidates within d̂: mollified EE when ‖e_a × e_b‖² < ε_x = 1e-3‖ē_a‖²‖ē_b‖² (rest
  lengths; the distance keeps its closest-feature type), else line–line (EE), EV or VV by type;
- an EV or VV pair found from several candidates (several faces or edge pairs) is one collision whose
  weight is that count (ipctk's convention; the original IPC sums over every point–triangle and
  edge–edge pair, duplicates included, which is the same energy).

Collision arrays (m collisions): ``verts`` (m, 4) collision-mesh vertex ids, −1 padded; ``kind`` the
distance kind (``PP``, ``PL``, ``PPLANE``, ``LL``); ``local`` (m, 4) which of ``verts`` form the
distance stencil, −1 padded; ``eps`` the mollifier threshold (0: not mollified); ``weight`` the
multiplicity; ``sqdist`` d at build.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from idp._leaf import leaf_njit
from idp.contact._distance_kernels import (
    EE_KIND,
    EE_LOCAL,
    EE_MOLLIFIER_FACTOR,
    PL,
    PP,
    PT_KIND,
    PT_LOCAL,
    barrier,
    barrier_first_derivative,
    barrier_second_derivative,
    edge_cross,
    edge_edge_type,
    ee_mollifier,
    ee_mollifier_gradient,
    ee_mollifier_hessian,
    gather_stencil,
    point_triangle_type,
    sq_distance,
    sq_distance_gradient,
    sq_distance_hessian,
)
from idp.contact._psd_projection import WORK_ROWS, project_psd
from idp.thread_choice import ThreadChoice
from idp.threaded import run_in_parts

#: Fewest items per thread of a kernel run in parts (idp.threaded): about 0.3 ms of work on the 2-core Intel VM
#: (classification 56 ns a candidate, value 57 ns, gradient 107 ns, Hessian block 1.9 µs a collision), since
#: handing a part to a thread costs ≈ 0.1 ms there; a smaller range runs on the calling thread alone.
GRAIN_CLASSIFY, GRAIN_VALUES, GRAIN_GRADIENTS, GRAIN_HESSIANS = 4096, 4096, 2048, 128


# --------------------------------------------------------------------------------------------------
# collision set
# --------------------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def _put_row(X, r, V, v):  # pragma: no cover - compiled
    """X[r] = V[v] for 3-vectors, element by element: the array assignment ``X[i] = V[v]`` compiles numba's
    shape-mismatch error path (string formatting, about 2 s of compile time in every process that compiles it),
    and a row view ``X[r]`` passed to a call costs two atomic reference-count updates."""
    X[r, 0] = V[v, 0]
    X[r, 1] = V[v, 1]
    X[r, 2] = V[v, 2]


@njit(cache=True, nogil=True, error_model="numpy")
def _classify_range(i0, i1, V, faces, edges, fv, ee, rest_len2, ctype, sqd, eps):  # pragma: no cover
    """Candidates i0..i1−1 (face–vertex first, then edge–edge): closest-feature type, squared distance,
    and for edge pairs the mollifier threshold ε_x when ‖e_a × e_b‖² < ε_x (else 0)."""
    X = np.empty((4, 3))
    S = np.empty((4, 3))
    nf = fv.shape[0]
    for i in range(i0, i1):
        if i < nf:
            f, v = fv[i, 0], fv[i, 1]
            _put_row(X, 0, V, v)
            _put_row(X, 1, V, faces[f, 0])
            _put_row(X, 2, V, faces[f, 1])
            _put_row(X, 3, V, faces[f, 2])
            t = point_triangle_type(X)
            gather_stencil(PT_LOCAL, t, X, S)
            ctype[i] = t
            sqd[i] = sq_distance(PT_KIND[t], S)  # reads only the rows of its kind
            eps[i] = 0.0
        else:
            ea, eb = ee[i - nf, 0], ee[i - nf, 1]
            _put_row(X, 0, V, edges[ea, 0])
            _put_row(X, 1, V, edges[ea, 1])
            _put_row(X, 2, V, edges[eb, 0])
            _put_row(X, 3, V, edges[eb, 1])
            t = edge_edge_type(X)
            gather_stencil(EE_LOCAL, t, X, S)
            ctype[i] = t
            sqd[i] = sq_distance(EE_KIND[t], S)
            threshold = EE_MOLLIFIER_FACTOR * rest_len2[ea] * rest_len2[eb]
            _a0, _a1, _a2, _b0, _b1, _b2, cx, cy, cz = edge_cross(X, 0, 1, 2, 3)
            eps[i] = threshold if cx * cx + cy * cy + cz * cz < threshold else 0.0


@njit(cache=True, parallel=True, error_model="numpy")
def _merge_repeated(key, verts, nv):  # pragma: no cover - compiled
    """keep[c] = False for every repeat of an earlier EV / VV collision with the same key (key >= 0; the first in
    index order is kept), weight[c] = how many it stands for. Bucketed by the first vertex (a counting sort, then
    an insertion sort within each vertex's few entries): the mannequin's 143,000 pairs within d̂ hold 31,000
    distinct ones, and an argsort of all keys was 80 % of the compaction."""
    m = key.size
    keep = np.ones(m, np.bool_)
    weight = np.ones(m)
    start = np.zeros(nv + 1, np.int64)
    for c in range(m):
        if key[c] >= 0:
            start[verts[c, 0] + 1] += 1
    for v in range(nv):
        start[v + 1] += start[v]
    at = start[:-1].copy()
    bucket = np.empty(start[nv], np.int64)
    for c in range(m):  # in index order, so each bucket lists its entries in index order
        if key[c] >= 0:
            v = verts[c, 0]
            bucket[at[v]] = c
            at[v] += 1
    for v in prange(nv):  # each vertex's bucket on its own (disjoint entries of bucket, keep and weight)
        lo, hi = start[v], start[v + 1]
        for i in range(lo + 1, hi):  # stable insertion sort by key: equal keys keep index order
            c = bucket[i]
            k = key[c]
            j = i - 1
            while j >= lo and key[bucket[j]] > k:
                bucket[j + 1] = bucket[j]
                j -= 1
            bucket[j + 1] = c
        i = lo
        while i < hi:
            first = bucket[i]
            e = i + 1
            while e < hi and key[bucket[e]] == key[first]:
                keep[bucket[e]] = False
                e += 1
            weight[first] = e - i
            i = e
    return keep, weight


@njit(cache=True, error_model="numpy")
def _compact_range(
    i0, i1, c, fv, ee, faces, edges, ctype, sqd, eps, dhat2, nv, verts, kind, local, eps_out, dist, key
):  # pragma: no cover - compiled
    """Rows c, c + 1, … of the active-collision arrays from candidates [i0, i1) (those with sqd < dhat2, in order)."""
    nf = fv.shape[0]
    X4 = np.empty(4, np.int64)
    for i in range(i0, i1):
        if sqd[i] >= dhat2:
            continue
        t = ctype[i]
        if i < nf:
            X4[0] = fv[i, 1]
            X4[1] = faces[fv[i, 0], 0]
            X4[2] = faces[fv[i, 0], 1]
            X4[3] = faces[fv[i, 0], 2]
            kd = PT_KIND[t]
            mollified = False
        else:
            X4[0] = edges[ee[i - nf, 0], 0]
            X4[1] = edges[ee[i - nf, 0], 1]
            X4[2] = edges[ee[i - nf, 1], 0]
            X4[3] = edges[ee[i - nf, 1], 1]
            kd = EE_KIND[t]
            mollified = eps[i] > 0.0
        kind[c] = kd
        dist[c] = sqd[i]
        for j in range(4):
            verts[c, j] = -1
            local[c, j] = -1
        eps_out[c] = 0.0
        key[c] = -1
        if mollified:  # all four vertices; the distance keeps its closest-feature stencil
            for j in range(4):
                verts[c, j] = X4[j]
                local[c, j] = EE_LOCAL[t, j]
            eps_out[c] = eps[i]
        else:
            for j in range(4):
                lj = PT_LOCAL[t, j] if i < nf else EE_LOCAL[t, j]
                if lj < 0:
                    break
                verts[c, j] = X4[lj]
                local[c, j] = j
            if kd == PP or kd == PL:
                p, q = np.int64(verts[c, 0]), np.int64(verts[c, 1])
                r = np.int64(verts[c, 2]) if kd == PL else np.int64(-1)
                if kd == PP and q < p:
                    p, q = q, p
                if kd == PL and r < q:
                    q, r = r, q
                verts[c, 0], verts[c, 1] = p, q
                if kd == PL:
                    verts[c, 2] = r
                key[c] = ((np.int64(kd) * nv + p) * nv + q) * (nv + 1) + (r + 1)
        c += 1


@njit(cache=True, parallel=True, error_model="numpy")
def _compact(fv, ee, faces, edges, ctype, sqd, eps, dhat2, nv):  # pragma: no cover - compiled
    """The unique active collisions from classified candidates (see the module docstring): point–plane,
    line–line and mollified edge pairs as they are; EV / VV pairs merged, their weight the count. The active
    candidates are counted and written in parallel chunks, in candidate order (the same arrays on any thread
    count); the merge sorts each first vertex's bucket in parallel."""
    n = fv.shape[0] + ee.shape[0]
    nch = max(1, min(64, n // 8192))
    at = np.empty(nch + 1, np.int64)
    for t in prange(nch):
        m = 0
        for i in range(t * n // nch, (t + 1) * n // nch):
            if sqd[i] < dhat2:
                m += 1
        at[t + 1] = m
    at[0] = 0
    for t in range(nch):
        at[t + 1] += at[t]
    m = at[nch]
    verts = np.empty((m, 4), np.int32)
    kind = np.empty(m, np.int8)
    local = np.empty((m, 4), np.int8)
    eps_out = np.empty(m)
    dist = np.empty(m)
    key = np.empty(m, np.int64)  # EV / VV only: (kind, point, sorted others); -1 otherwise
    for t in prange(nch):
        _compact_range(
            t * n // nch,
            (t + 1) * n // nch,
            at[t],
            fv,
            ee,
            faces,
            edges,
            ctype,
            sqd,
            eps,
            dhat2,
            nv,
            verts,
            kind,
            local,
            eps_out,
            dist,
            key,
        )
    keep, weight = _merge_repeated(key, verts, nv)
    mk = 0
    for i in range(m):
        if keep[i]:
            mk += 1
    out = np.empty(mk, np.int64)
    mk = 0
    for i in range(m):
        if keep[i]:
            out[mk] = i
            mk += 1
    return verts[out], kind[out], local[out], eps_out[out], weight[out], dist[out]


_COMPACT_THREADS = ThreadChoice()


class CollisionSet:
    """Active IPC collisions at one configuration, as arrays (see the module docstring)."""

    __slots__ = ("eps", "kind", "local", "sqdist", "verts", "weight")

    def __init__(self, verts, kind, local, eps, weight, sqdist):
        self.verts, self.kind, self.local, self.eps = verts, kind, local, eps
        self.weight, self.sqdist = weight, sqdist

    def __len__(self) -> int:
        return int(self.kind.size)

    @staticmethod
    def empty() -> CollisionSet:
        return CollisionSet(
            np.zeros((0, 4), np.int32),
            np.zeros(0, np.int8),
            np.zeros((0, 4), np.int8),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0),
        )


def classify(
    V: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    fv: np.ndarray,
    ee: np.ndarray,
    rest_len2: np.ndarray,
    ctype: np.ndarray,
    sqd: np.ndarray,
    eps: np.ndarray,
) -> None:
    """Fill ``ctype``, ``sqd`` (squared distance) and ``eps`` (mollifier threshold, 0: none) of every (``fv``, then
    ``ee``) candidate at positions ``V``, on every thread."""
    n = fv.shape[0] + ee.shape[0]
    run_in_parts(_classify_range, n, V, faces, edges, fv, ee, rest_len2, ctype, sqd, eps, grain=GRAIN_CLASSIFY)


def build_collision_set(
    V: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    fv: np.ndarray,
    ee: np.ndarray,
    dhat: float,
    rest_len2: np.ndarray,
) -> CollisionSet:
    """Classify face–vertex (``fv`` rows [face, vertex]) and edge–edge (``ee`` rows [edge a, edge b])
    candidates at positions ``V`` into the unique active collisions (squared distance < d̂²).
    ``rest_len2``: squared rest length of every edge (mollifier thresholds)."""
    n = fv.shape[0] + ee.shape[0]
    if n == 0:
        return CollisionSet.empty()
    ctype = np.empty(n, np.int64)
    sqd = np.empty(n)
    eps = np.empty(n)
    classify(V, faces, edges, fv, ee, rest_len2, ctype, sqd, eps)
    dhat2, nv = float(dhat) ** 2, V.shape[0]
    # its parallel regions cost more than they save on small sets (idp.thread_choice; the same arrays either way)
    return CollisionSet(*_COMPACT_THREADS.run(n, lambda: _compact(fv, ee, faces, edges, ctype, sqd, eps, dhat2, nv)))


# --------------------------------------------------------------------------------------------------
# value, gradient, Hessian blocks
# --------------------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def _gather(V, verts, local, c, X, S):  # pragma: no cover - compiled
    """X ← the collision's vertices (returns their count n), S ← its distance stencil (returns k)."""
    n = 0
    while n < 4 and verts[c, n] >= 0:
        _put_row(X, n, V, verts[c, n])
        n += 1
    return n, gather_stencil(local, c, X, S)


@njit(cache=True, nogil=True, error_model="numpy")
def _values_chunk(c0, c1, V, verts, kind, local, eps, weight, dhat2, out):  # pragma: no cover - compiled
    X = np.empty((4, 3))
    S4 = np.empty((4, 3))
    for c in range(c0, c1):
        _gather(V, verts, local, c, X, S4)
        d = sq_distance(np.int64(kind[c]), S4)  # int64 as in _classify_range: one compiled sq_distance
        b = barrier(d, dhat2)
        if eps[c] > 0.0:
            b *= ee_mollifier(X, eps[c])
        out[c] = weight[c] * b


@njit(cache=True, nogil=True, error_model="numpy")
def _gradients_chunk(c0, c1, V, verts, kind, local, eps, weight, dhat2, out):  # pragma: no cover - compiled
    """out[c, :3n] = weight·∇(m b) of collision c on its n vertices (vertex-major)."""
    X = np.empty((4, 3))
    S4 = np.empty((4, 3))
    gd = np.empty(12)
    gm = np.empty(12)
    for c in range(c0, c1):
        _n, k = _gather(V, verts, local, c, X, S4)
        d = sq_distance_gradient(kind[c], S4, gd)
        b1 = barrier_first_derivative(d, dhat2)
        for j in range(12):
            out[c, j] = 0.0
        w = weight[c]
        m = 1.0
        if eps[c] > 0.0:
            m = ee_mollifier_gradient(X, eps[c], gm)
            b = barrier(d, dhat2)
            for j in range(12):
                out[c, j] = w * b * gm[j]
        for a in range(k):
            la = local[c, a]
            for r in range(3):
                out[c, 3 * la + r] += w * m * b1 * gd[3 * a + r]


@njit(cache=True, nogil=True, error_model="numpy")
def _hessian_chunk(
    c0, c1, V, verts, kind, local, eps, weight, dhat2, kappa, vertex_map, project, block_verts, blocks
):  # pragma: no cover - compiled
    X = np.empty((4, 3))
    S4 = np.empty((4, 3))
    gd = np.empty(12)
    Hd = np.empty((12, 12))
    gm = np.empty(12)
    Hm = np.empty((12, 12))
    g = np.empty(12)  # ∇d on the collision's vertices
    H = np.empty((12, 12))
    R = np.empty((12, 12))
    work = np.empty((WORK_ROWS, 12))
    keep = np.empty(4, np.int64)
    for c in range(c0, c1):
        n, k = _gather(V, verts, local, c, X, S4)
        d = sq_distance_hessian(kind[c], S4, gd, Hd)
        b = barrier(d, dhat2)
        b1 = barrier_first_derivative(d, dhat2)
        b2 = barrier_second_derivative(d, dhat2)
        nd = 3 * n
        for i in range(nd):
            g[i] = 0.0
            for j in range(nd):
                H[i, j] = 0.0
        for a in range(k):  # embed the stencil's derivatives into the collision's vertex order
            la = local[c, a]
            for r in range(3):
                g[3 * la + r] = gd[3 * a + r]
                for bb in range(k):
                    lb = local[c, bb]
                    for s in range(3):
                        H[3 * la + r, 3 * lb + s] = Hd[3 * a + r, 3 * bb + s]
        m = 1.0
        if eps[c] > 0.0:
            m = ee_mollifier_hessian(X, eps[c], gm, Hm)
        for i in range(nd):
            for j in range(nd):
                H[i, j] = m * (b2 * g[i] * g[j] + b1 * H[i, j])
        if eps[c] > 0.0:
            for i in range(nd):
                for j in range(nd):
                    H[i, j] += b1 * (g[i] * gm[j] + gm[i] * g[j]) + b * Hm[i, j]
        # keep the optimised vertices only, then project that block
        kw = kappa * weight[c]
        nk = 0
        for a in range(n):
            if vertex_map[verts[c, a]] >= 0:
                keep[nk] = a
                nk += 1
        for a in range(4):
            block_verts[c, a] = vertex_map[verts[c, keep[a]]] if a < nk else -1
        for a in range(nk):
            for r in range(3):
                for bb in range(nk):
                    for s in range(3):
                        R[3 * a + r, 3 * bb + s] = kw * H[3 * keep[a] + r, 3 * keep[bb] + s]
        if project and nk > 0:
            project_psd(R, 3 * nk, work)
        for i in range(3 * nk):
            for j in range(3 * nk):
                blocks[c, i, j] = R[i, j]


@njit(cache=True, error_model="numpy")
def _accumulate_gradient(verts, local_grads, out):  # pragma: no cover - compiled
    for c in range(verts.shape[0]):
        for a in range(4):
            v = verts[c, a]
            if v < 0:
                break
            for r in range(3):
                out[3 * v + r] += local_grads[c, 3 * a + r]


def _collision_arrays(cs: CollisionSet, dhat: float) -> tuple:
    """The per-collision arguments of the value, gradient and Hessian kernels, and d̂²."""
    return cs.verts, cs.kind, cs.local, cs.eps, cs.weight, float(dhat) ** 2


def barrier_value(cs: CollisionSet, V: np.ndarray, dhat: float, kappa: float) -> float:
    """κ Σ m b(d) over the collision set at positions ``V``."""
    if len(cs) == 0:
        return 0.0
    out = np.empty(len(cs))
    run_in_parts(_values_chunk, len(cs), V, *_collision_arrays(cs, dhat), out, grain=GRAIN_VALUES)
    return float(kappa * out.sum())


def barrier_gradient(cs: CollisionSet, V: np.ndarray, dhat: float, kappa: float) -> np.ndarray:
    """Gradient on the collision-mesh DOFs (interleaved, length 3·len(V))."""
    g = np.zeros(V.size)
    if len(cs) == 0:
        return g
    local = np.empty((len(cs), 12))
    run_in_parts(_gradients_chunk, len(cs), V, *_collision_arrays(cs, dhat), local, grain=GRAIN_GRADIENTS)
    _accumulate_gradient(cs.verts, local, g)
    return kappa * g


def barrier_hessian_blocks(
    cs: CollisionSet,
    V: np.ndarray,
    dhat: float,
    kappa: float,
    vertex_map: np.ndarray,
    project: bool = True,
    out: tuple[np.ndarray, np.ndarray] | None = None,
    rows: tuple[int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-collision Hessian blocks on the optimised vertices only.

    ``vertex_map``: (len(V),) int64, the output numbering of each collision-mesh vertex, −1 for a vertex
    that is not optimised (static obstacle, pinned). Returns ``block_verts`` (m, 4) int32 (output ids,
    −1 padded) and ``blocks`` (m, 12, 12): the leading 3n×3n of block c belongs to its n kept vertices
    (vertex-major); with ``project`` each block is projected to PSD after the restriction. ``out``: C-contiguous
    (m, 4) int32 and (m, 12, 12) float64 arrays to write into (rows of larger arrays, or a buffer reused range
    after range). ``rows``: (c0, c1), the blocks of collisions c0 … c1 − 1 only (m = c1 − c0; the same kernel on
    views of the collision arrays, so each block is the one the whole set would give)."""
    arrays = _collision_arrays(cs, dhat)
    m = len(cs)
    if rows is not None:
        c0, c1 = int(rows[0]), int(rows[1])
        if not 0 <= c0 <= c1 <= m:
            raise ValueError(f"rows {rows} outside the {m} collisions")
        verts, kind, local, eps, weight, dhat2 = arrays
        arrays = (verts[c0:c1], kind[c0:c1], local[c0:c1], eps[c0:c1], weight[c0:c1], dhat2)
        m = c1 - c0
    if out is None:
        block_verts, blocks = np.empty((m, 4), np.int32), np.empty((m, 12, 12))
    else:
        block_verts, blocks = out
        if block_verts.shape != (m, 4) or blocks.shape != (m, 12, 12):
            raise ValueError(f"out arrays of shapes {block_verts.shape}, {blocks.shape} for {m} collisions")
        if not (block_verts.flags.c_contiguous and blocks.flags.c_contiguous):
            raise ValueError("out arrays must be C-contiguous")
    if m:
        run_in_parts(
            _hessian_chunk,
            m,
            V,
            *arrays,
            float(kappa),
            np.ascontiguousarray(vertex_map, dtype=np.int64),
            bool(project),
            block_verts,
            blocks,
            grain=GRAIN_HESSIANS,
        )
    return block_verts, blocks


def blocks_to_coo(block_verts: np.ndarray, blocks: np.ndarray, d: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, values) of the blocks in the output DOF numbering (vertex id · d + component)."""
    m = block_verts.shape[0]
    if m == 0:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0)
    dof = (block_verts.astype(np.int64)[:, :, None] * d + np.arange(d)[None, None, :]).reshape(m, 4 * d)
    dof[np.repeat(block_verts < 0, d, axis=1)] = -1
    rows = np.broadcast_to(dof[:, :, None], (m, 4 * d, 4 * d))
    cols = np.broadcast_to(dof[:, None, :], (m, 4 * d, 4 * d))
    keep = (rows >= 0) & (cols >= 0)
    return rows[keep], cols[keep], blocks[keep]


def minimum_sqdist(cs: CollisionSet) -> float:
    return float(cs.sqdist.min()) if len(cs) else float("inf")
