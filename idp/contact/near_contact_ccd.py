"""Conservative advancement for nearly touching surface pairs, with exact primitive distances (3D: point–triangle
and edge–edge; 2D: point–segment).

Why: Tight Inclusion degenerates on pairs that already nearly touch (minutes and gigabytes for one
query at a 1e-15 gap), and ipctk's additive CCD, used instead there, is not provably conservative:
at gaps of ~1e-10 it returned α = 1 for a move that crossed (Fig. 3 armadillo, step 104).  A plain
Lipschitz bound (no gap may fall by more than the step's largest displacement) is safe but blind to
direction: a pair that slides along itself at a constant 1e-8 gap, such as a sliver triangle's vertex
against the edge it nearly lies on (the cat of Fig. 12 has one), freezes the whole surface at
α ≈ 1e-7.

Here each nearly touching primitive pair (point–triangle or edge–edge) is advanced along the linear
move with the classic bound: for primitives with vertices a_i and b_j and any vector c, the closest
points' difference moves by at most l = max_i |Δa_i − c| + max_j |Δb_j − c| per unit α (c = the mean
displacement of the pair, which removes a common translation), so from a gap g at α the gap stays above
``keep``·g₀ until α + (g − keep·g₀)/l.  Gaps are recomputed exactly (closest-feature classification,
then the feature distance) at every advance, with a rounding allowance subtracted, so the bound is
conservative and tangential sliding costs iterations, not step length.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from idp.contact._distance_kernels import (
    EE_KIND,
    EE_LOCAL,
    PT_KIND,
    PT_LOCAL,
    edge_edge_type,
    gather_stencil,
    point_triangle_type,
    sq_distance,
)

#: largest number of advances per pair; a pair that needs more stops where it is (conservative).  A pair sliding
#: at a gap g with relative speed l needs ≈ 2 l / g advances per unit of α: the cat's sliver (g = 1e-8, l ≈ 1e-3)
#: 2e5.  With 1e6, the Fig. 3 armadillo's torso pressed into its legs (gaps 1e-10–1e-9) spent up to 1.6 s per
#: CCD call; 2.5e5 bounds a pair's cost to a few ms at the price of a shorter step for such pairs.
MAX_ADVANCES = 250_000
#: A pair stops advancing once its gap is within this factor of the gap it must keep (``keep``·g₀): it has
#: arrived. Without it a pair closing in on that floor took ever smaller advances, each ``(g − floor)/l``, until
#: α stopped changing in floating point, then ran to MAX_ADVANCES: 15–20 ms a pair (the beam loop of
#: tests/stepper/test_handles.py, edge–edge pairs at g₀ = 2.1e-5 meeting their floor of 6.2e-7 at α = 0.0695).
#: Stopping within 10 % of the floor shortens such a pair's step by about that share of its last approach.
ARRIVED = 1.1


POINT_TRIANGLE, EDGE_EDGE, POINT_SEGMENT = 0, 1, 2  # pair kinds; a 2D point–segment pair is padded to z = 0


def _kinds(is_point_triangle: np.ndarray) -> np.ndarray:
    return np.where(np.asarray(is_point_triangle, dtype=bool), POINT_TRIANGLE, EDGE_EDGE).astype(np.int64)


@njit(cache=True, error_model="numpy")
def _point_segment_distance(X):  # pragma: no cover - compiled
    """Exact distance from point X[0] to segment X[1]X[2]; a zero-length segment is the point X[1]. Interior
    feature: |e × q| / |e| (no subtraction of a projected point, which loses digits at tiny gaps)."""
    e = X[2] - X[1]
    q = X[0] - X[1]
    L2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    t = (q[0] * e[0] + q[1] * e[1] + q[2] * e[2]) / L2 if L2 > 0.0 else 0.0
    if t <= 0.0:
        return np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    if t >= 1.0:
        return np.sqrt((X[0, 0] - X[2, 0]) ** 2 + (X[0, 1] - X[2, 1]) ** 2 + (X[0, 2] - X[2, 2]) ** 2)
    cx = e[1] * q[2] - e[2] * q[1]
    cy = e[2] * q[0] - e[0] * q[2]
    cz = e[0] * q[1] - e[1] * q[0]
    return np.sqrt(cx * cx + cy * cy + cz * cz) / np.sqrt(L2)


@njit(cache=True, error_model="numpy")
def _pair_distance(X, S, kind):  # pragma: no cover - compiled
    """Exact (closest-feature) distance of the pair X: point X[0] vs triangle X[1:4], edge X[0:2] vs edge X[2:4],
    or point X[0] vs segment X[1:3]."""
    if kind == POINT_TRIANGLE:
        t = point_triangle_type(X)
        gather_stencil(PT_LOCAL, t, X, S)
        return np.sqrt(max(sq_distance(PT_KIND[t], S), 0.0))
    if kind == EDGE_EDGE:
        t = edge_edge_type(X)
        gather_stencil(EE_LOCAL, t, X, S)
        return np.sqrt(max(sq_distance(EE_KIND[t], S), 0.0))
    return _point_segment_distance(X)


@njit(cache=True, error_model="numpy")
def _advance_pair(V0, dV, ids, kind, alpha_max, keep, max_advances):  # pragma: no cover
    X = np.empty((4, 3))
    S = np.empty((4, 3))
    D = np.empty((4, 3))
    scale = 0.0
    for r in range(4):
        for c in range(3):
            X[r, c] = V0[ids[r], c]
            D[r, c] = dV[ids[r], c]
            scale = max(scale, abs(X[r, c]) + abs(D[r, c]))
    split = 2 if kind == EDGE_EDGE else 1  # vertices [0, split) form the first primitive
    mean = np.zeros(3)
    for r in range(4):
        for c in range(3):
            mean[c] += 0.25 * D[r, c]
    la = 0.0
    lb = 0.0
    for r in range(4):
        m = np.sqrt((D[r, 0] - mean[0]) ** 2 + (D[r, 1] - mean[1]) ** 2 + (D[r, 2] - mean[2]) ** 2)
        if r < split:
            la = max(la, m)
        else:
            lb = max(lb, m)
    lip = la + lb
    if lip == 0.0:
        return alpha_max
    slack = 64.0 * 2.220446049250313e-16 * scale  # rounding allowance on a computed gap
    g0 = _pair_distance(X, S, kind)
    target = keep * g0
    alpha = 0.0
    g = g0
    for _ in range(max_advances):
        if g - slack <= ARRIVED * target:
            return alpha
        step = (g - slack - target) / lip
        alpha += step
        if alpha >= alpha_max:
            return alpha_max
        for r in range(4):
            for c in range(3):
                X[r, c] = V0[ids[r], c] + alpha * D[r, c]
        g = _pair_distance(X, S, kind)
    return alpha


@njit(cache=True, parallel=True, error_model="numpy")
def _advance_all(V0, dV, pairs, kinds, alpha_max, keep, max_advances, out):  # pragma: no cover
    for i in prange(pairs.shape[0]):
        out[i] = _advance_pair(V0, dV, pairs[i], kinds[i], alpha_max, keep, max_advances)


def conservative_step_2d(
    V0: np.ndarray, V1: np.ndarray, pairs: np.ndarray, alpha_max: float = 1.0, keep: float = 0.5
) -> float:
    """2D: largest α ≤ ``alpha_max`` found by conservative advancement such that every pair's gap stays above
    ``keep`` times its gap at V0 along V0 → V0 + α(V1 − V0). ``pairs``: (k, 3) vertex ids, a point and a segment
    (a vertex–vertex pair repeats its second vertex). The 3D kernel on the plane z = 0."""
    pairs = np.asarray(pairs, dtype=np.int64)
    V0_3, V1_3 = (np.pad(np.asarray(V, dtype=float), ((0, 0), (0, 1))) for V in (V0, V1))
    rows = np.concatenate([pairs, pairs[:, 2:3]], axis=1)  # the 4th stencil row repeats the segment's end
    return _conservative_step(V0_3, V1_3, rows, np.full(pairs.shape[0], POINT_SEGMENT), alpha_max, keep)


def candidate_pairs(
    edges: np.ndarray, faces: np.ndarray, fv: np.ndarray, ee: np.ndarray, which: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The broad-phase candidates ``which`` (indices into fv rows then ee rows, as the compiled broad phase returns
    them) as ((k, 4) vertex ids, (k,) is_point_triangle)."""
    which = np.asarray(which, dtype=np.int64)
    nf = fv.shape[0]
    f_sel = np.asarray(fv, dtype=np.int64).reshape(-1, 2)[which[which < nf]]
    e_sel = np.asarray(ee, dtype=np.int64).reshape(-1, 2)[which[which >= nf] - nf]
    F = np.asarray(faces, dtype=np.int64)
    E = np.asarray(edges, dtype=np.int64)
    pairs = np.empty((f_sel.shape[0] + e_sel.shape[0], 4), dtype=np.int64)
    pairs[: f_sel.shape[0], 0] = f_sel[:, 1]
    pairs[: f_sel.shape[0], 1:] = F[f_sel[:, 0]]
    pairs[f_sel.shape[0] :, :2] = E[e_sel[:, 0]]
    pairs[f_sel.shape[0] :, 2:] = E[e_sel[:, 1]]
    is_pt = np.zeros(pairs.shape[0], dtype=bool)
    is_pt[: f_sel.shape[0]] = True
    return pairs, is_pt


def near_pairs(
    V: np.ndarray, edges: np.ndarray, faces: np.ndarray, fv: np.ndarray, ee: np.ndarray, max_distance: float
) -> tuple[np.ndarray, np.ndarray]:
    """The candidate pairs closer than ``max_distance`` at V, as ((k, 4) vertex ids, (k,) is_point_triangle).

    ``fv`` rows are (face, vertex), ``ee`` rows (edge, edge), as the compiled broad phase returns them."""
    fv = np.asarray(fv).reshape(-1, 2)
    ee = np.asarray(ee).reshape(-1, 2)
    pairs, is_pt = candidate_pairs(edges, faces, fv, ee, np.arange(fv.shape[0] + ee.shape[0]))
    if pairs.shape[0] == 0:
        return pairs, is_pt
    d = pair_distances(V, pairs, is_pt)
    keep = d < max_distance
    return pairs[keep], is_pt[keep]


@njit(cache=True, parallel=True, error_model="numpy")
def _distances_kernel(V, pairs, kinds, out):  # pragma: no cover - compiled
    for i in prange(pairs.shape[0]):
        X = np.empty((4, 3))
        S = np.empty((4, 3))
        for r in range(4):
            for c in range(3):
                X[r, c] = V[pairs[i, r], c]
        out[i] = _pair_distance(X, S, kinds[i])


def pair_distances(V: np.ndarray, pairs: np.ndarray, is_point_triangle: np.ndarray) -> np.ndarray:
    """Exact distance of each pair (rows of 4 vertex ids; point–triangle or edge–edge) at V."""
    out = np.empty(pairs.shape[0])
    _distances_kernel(
        np.ascontiguousarray(V, dtype=float),
        np.ascontiguousarray(pairs, dtype=np.int64),
        _kinds(is_point_triangle),
        out,
    )
    return out


def conservative_step(
    V0: np.ndarray,
    V1: np.ndarray,
    pairs: np.ndarray,
    is_point_triangle: np.ndarray,
    alpha_max: float = 1.0,
    keep: float = 0.5,
) -> float:
    """Largest α ≤ ``alpha_max`` found by conservative advancement such that every pair's gap stays above
    ``keep`` times its gap at V0 along V0 → V0 + α(V1 − V0)."""
    return _conservative_step(V0, V1, pairs, _kinds(is_point_triangle), alpha_max, keep)


def _conservative_step(
    V0: np.ndarray, V1: np.ndarray, pairs: np.ndarray, kinds: np.ndarray, alpha_max: float, keep: float
) -> float:
    """:func:`conservative_step` for (k, 4) stencils of any pair kind (``POINT_TRIANGLE``, ...)."""
    if pairs.shape[0] == 0 or alpha_max <= 0.0:
        return float(max(alpha_max, 0.0))
    V0 = np.ascontiguousarray(V0, dtype=float)
    dV = np.ascontiguousarray(V1, dtype=float) - V0
    out = np.empty(pairs.shape[0])
    _advance_all(
        V0,
        dV,
        np.ascontiguousarray(pairs, dtype=np.int64),
        np.ascontiguousarray(kinds, dtype=np.int64),
        float(alpha_max),
        float(keep),
        MAX_ADVANCES,
        out,
    )
    return float(min(alpha_max, out.min()))
