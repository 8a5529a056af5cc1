"""Which broad-phase candidates of a linear move can limit its CCD step, and which can be active in a line search.

For two primitives with vertices a_i and b_j moving linearly by Δa_i, Δb_j over the move (fraction α from 0 to
1), any point difference p(α) − q(α) = Σ λ_i μ_j (a_i(α) − b_j(α)) (barycentric λ, μ) changes by
α·Σ λ_i μ_j (Δa_i − Δb_j), whose length is at most α·M with M = max_ij |Δa_i − Δb_j|. So from any fraction t the
pair's distance obeys d(α) ≥ d(t) − (α − t)·M. :func:`move_bounds` computes, per candidate and in one parallel
pass, d(0) (by the closest-feature code of the barrier), M, and by conservative advancement (at most ``ADVANCES``
exact distance evaluations, each gap reduced by a rounding allowance) a fraction ``first`` before which the pair's
distance provably stays above (1 − r)·d(0) > 0, r the narrow phase's conservative rescaling.

Two uses (:meth:`idp.contact.model.ContactModel.max_collision_free_step` and
:meth:`~idp.contact.model.ContactModel.line_search_candidates`):

- CCD: ipctk's Tight Inclusion looks, for each pair, for the first time its distance falls to
  min((1 − r)·d(0), 1e-4) (ipctk's conservative rescaling r; its additive CCD to about (1 − r)·d(0)). A pair whose
  ``first`` is past the step α that CCD allows stays farther than (1 − r)·d(0) on [0, α]: it cannot collide
  there. So the candidates are taken by increasing ``first``, in batches doubling from FIRST_BATCH; the pairs of a
  batch are first advanced further (:func:`refine`, at most REFINE_ADVANCES more distance evaluations, up to the
  step found so far), and only those still below it go to the narrow phase; the loop stops once the next
  ``first`` is past the step found so far. Each pair left out keeps at least (1 − r)·d(0), the gap the narrow
  phase would keep; only Tight Inclusion's own error margin (its tolerance, up to 1e-4) can make the step
  larger than ipctk's over all candidates. Measured on recorded moves (r = 0.97): bunny_700 (50 moves) and
  bunny_3376 (34) the very α of ipctk's ``compute_collision_free_stepsize`` (Tight Inclusion with its own broad
  phase) on every move, 4.6 against 7.7 ms and 10.0 against 30.7 ms per call (machine shared); tube_in_tube
  (26 moves, 60K–84K candidates, buckling self-contact) equal on 22, larger on 4 (at most +12.5 %), 50 against
  191 ms (another series: 128 ms per move without the further advancement, 44 ms with it). At r = 0.8 (before
  the further advancement) ≈ 470 and ≈ 190 candidates per move were left for Tight Inclusion at bunny_700 and
  bunny_3376; with M alone, no advancement, 1,500 / 2,100.
- Line search: a trial point at fraction s ≤ α of the move can only hold pairs with d(0) − s·M < d̂, so the
  trial collision sets are classified from those candidates alone (the same collision set: the others are
  provably farther than d̂ there, and dropping them keeps the order of the rest).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from idp._leaf import leaf_njit
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

#: Relative allowance on the distance bound when trimming the line-search candidates (rounding of d(0) and M).
TRIM_SLACK = 1e-9
#: Distance evaluations of the conservative advancement per candidate (bunny_3376: 0 → 3,200 candidates left for
#: the narrow phase per move, 2 → 460, 4 → 270).
ADVANCES = 2
#: Further distance evaluations per candidate before it goes to the narrow phase (:func:`refine`); tube_in_tube's
#: recorded moves: 0 → 128 ms per call, 8 → 60 ms, 32 → 44 ms, 128 → 39 ms (bunnies: no change).
REFINE_ADVANCES = 32
#: First narrow-phase batch; each next one is twice as large.
FIRST_BATCH = 256

_CHUNK = 512


@leaf_njit(error_model="numpy")
def _distance(X, S, point_triangle):  # pragma: no cover - compiled
    if point_triangle:
        t = point_triangle_type(X)
        gather_stencil(PT_LOCAL, t, X, S)
        return np.sqrt(max(sq_distance(PT_KIND[t], S), 0.0))
    t = edge_edge_type(X)
    gather_stencil(EE_LOCAL, t, X, S)
    return np.sqrt(max(sq_distance(EE_KIND[t], S), 0.0))


@njit(cache=True, error_model="numpy")
def _bounds_range(  # pragma: no cover - compiled
    i0, i1, V0, V1, faces, edges, fv, ee, keep, keep2, advances, min_gap, dist, speed, first, first2
):
    X = np.empty((4, 3))
    X0 = np.empty((4, 3))  # the pair's vertices at the start of the move
    S = np.empty((4, 3))
    D = np.empty((4, 3))
    nf = fv.shape[0]
    for i in range(i0, i1):
        pt = i < nf
        scale = 0.0
        check = 0.0  # NaN or inf unless every coordinate is finite
        for r in range(4):
            # vertex r of the pair: point, triangle (face–vertex candidates, the first nf) or edge, edge — indexed
            # here, not by a helper: numba increfs and decrefs the arrays a compiled callee binds, even one it
            # inlines (`inline="always"`), and faces and edges are shared by both threads (4 × 4 atomic updates a
            # pair, the largest share of the run's reference counting on bunny_700)
            if pt:
                v = fv[i, 1] if r == 0 else faces[fv[i, 0], r - 1]
            else:
                v = edges[ee[i - nf, r // 2], r % 2]
            for c in range(3):
                X[r, c] = V0[v, c]
                X0[r, c] = V0[v, c]
                D[r, c] = V1[v, c] - V0[v, c]
                scale = max(scale, abs(X[r, c]) + abs(D[r, c]))
                check += X[r, c] * 0.0 + D[r, c] * 0.0
        split = 1 if pt else 2
        m2 = 0.0
        for a in range(split):
            for b in range(split, 4):
                s2 = 0.0
                for c in range(3):
                    e = D[a, c] - D[b, c]
                    s2 += e * e
                m2 = max(m2, s2)
        m = np.sqrt(m2)
        slack = 64.0 * 2.220446049250313e-16 * scale
        if check == 0.0 and m > 0.0:
            # the gap between the two primitives' boxes at the start is a lower bound of d(0): when it alone shows
            # the pair cannot close to keep·d(0) within the move, skip the exact distance (see move_bounds)
            gap = 0.0
            for c in range(3):
                lo_a = X[0, c]
                hi_a = X[0, c]
                for r in range(1, split):
                    lo_a = min(lo_a, X[r, c])
                    hi_a = max(hi_a, X[r, c])
                lo_b = X[split, c]
                hi_b = X[split, c]
                for r in range(split + 1, 4):
                    lo_b = min(lo_b, X[r, c])
                    hi_b = max(hi_b, X[r, c])
                gap = max(gap, lo_b - hi_a, lo_a - hi_b)
            t1 = ((1.0 - keep) * gap - slack) / m
            t2 = ((1.0 - keep2) * gap - slack) / m if keep2 > 0.0 else np.inf
            if gap >= min_gap and t1 >= 1.0 and t2 >= 1.0:
                dist[i] = gap
                speed[i] = m
                first[i] = t1
                if keep2 > 0.0:
                    first2[i] = t2
                continue
        d0 = _distance(X, S, pt)
        if check != 0.0:  # non-finite positions: never filtered away
            dist[i] = 0.0
            speed[i] = np.inf
            first[i] = 0.0
            if keep2 > 0.0:
                first2[i] = 0.0
            continue
        dist[i] = d0
        speed[i] = m
        if m == 0.0:
            first[i] = np.inf  # no relative motion: the distance is constant
            if keep2 > 0.0:
                first2[i] = np.inf
            continue
        # conservative advancement towards keep·d0: from a gap g at t the gap stays above keep·d0 until
        # t + (g − slack − keep·d0) / M (slack: rounding of a computed gap)
        target = keep * d0
        t = (d0 - slack - target) / m
        first[i] = _advance(X0, D, X, S, pt, t, target, slack, m, advances, 1.0)
        if keep2 > 0.0:  # the same for a second narrow phase's keep, from the same start
            target = keep2 * d0
            t = (d0 - slack - target) / m
            first2[i] = _advance(X0, D, X, S, pt, t, target, slack, m, advances, 1.0)


@leaf_njit(error_model="numpy")
def _advance(X0, D, X, S, pt, t, target, slack, m, advances, limit):  # pragma: no cover - compiled
    """Conservative advancement of one pair (start positions ``X0``, moves ``D``; X, S scratch, all (4, 3) and the
    calling thread's own) from fraction t, where its gap is known to stay above ``target`` on [0, t]: at most
    ``advances`` exact distance evaluations, stopping at ``limit``; returns the new t (≥ 0)."""
    it = 0
    going = True  # a condition, not ``break``: see idp.contact._distance_kernels' docstring
    while going and it < advances:
        if not (0.0 < t < limit):
            going = False
        else:
            for r in range(4):
                for c in range(3):
                    X[r, c] = X0[r, c] + t * D[r, c]
            step = (_distance(X, S, pt) - slack - target) / m
            if step > 0.0:
                t += step
            else:
                going = False
        it += 1
    return max(t, 0.0)


@njit(cache=True, error_model="numpy")
def _refine_range(
    j0, j1, idx, V0, V1, faces, edges, fv, ee, keep, advances, limit, dist, speed, first
):  # pragma: no cover
    X = np.empty((4, 3))
    X0 = np.empty((4, 3))
    S = np.empty((4, 3))
    D = np.empty((4, 3))
    nf = fv.shape[0]
    for j in range(j0, j1):
        i = idx[j]
        t = first[i]
        m = speed[i]
        if not (0.0 < t < limit) or not (m < np.inf):
            continue
        pt = i < nf
        scale = 0.0
        for r in range(4):
            if pt:  # vertex r of the pair, indexed here (see _bounds_range)
                v = fv[i, 1] if r == 0 else faces[fv[i, 0], r - 1]
            else:
                v = edges[ee[i - nf, r // 2], r % 2]
            for c in range(3):
                X0[r, c] = V0[v, c]
                D[r, c] = V1[v, c] - V0[v, c]
                scale = max(scale, abs(V0[v, c]) + abs(D[r, c]))
        slack = 64.0 * 2.220446049250313e-16 * scale
        first[i] = _advance(X0, D, X, S, pt, t, keep * dist[i], slack, m, advances, limit)


@njit(cache=True, parallel=True, error_model="numpy")
def _refine(idx, V0, V1, faces, edges, fv, ee, keep, advances, limit, dist, speed, first):  # pragma: no cover
    n = idx.size
    for ch in prange((n + 63) // 64):
        _refine_range(
            ch * 64,
            min(n, (ch + 1) * 64),
            idx,
            V0,
            V1,
            faces,
            edges,
            fv,
            ee,
            keep,
            advances,
            limit,
            dist,
            speed,
            first,
        )


@njit(cache=True, parallel=True, error_model="numpy")
def _bounds(
    V0, V1, faces, edges, fv, ee, keep, keep2, advances, min_gap, dist, speed, first, first2
):  # pragma: no cover
    n = fv.shape[0] + ee.shape[0]
    for ch in prange((n + _CHUNK - 1) // _CHUNK):
        _bounds_range(
            ch * _CHUNK,
            min(n, (ch + 1) * _CHUNK),
            V0,
            V1,
            faces,
            edges,
            fv,
            ee,
            keep,
            keep2,
            advances,
            min_gap,
            dist,
            speed,
            first,
            first2,
        )


def move_bounds(
    V0: np.ndarray,
    V1: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    fv: np.ndarray,
    ee: np.ndarray,
    rescaling: float,
    second_rescaling: float | None = None,
    min_gap: float = np.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(d(0), M, t, t₂) of every candidate (face–vertex rows [face, vertex] first, then edge–edge rows [edge, edge])
    for the linear move V0 → V1: its distance at V0, the largest relative displacement of a vertex of one primitive
    against a vertex of the other, and a fraction of the move before which its distance provably stays above
    (1 − ``rescaling``)·d(0) (conservative advancement, at most ADVANCES distance evaluations; ≥ 1: the whole
    move). t₂: the same for ``second_rescaling`` (a second narrow phase the caller may choose once it knows d(0)),
    computed in the same pass; None when not asked for.

    A pair whose boxes at V0 are at least ``min_gap`` apart, a gap that alone keeps t (and t₂) ≥ 1, gets that gap
    as its d(0) — a lower bound — without the exact distance (on the mannequin about half the candidates of a
    Newton move). The CCD order (t < 1) is then the same as with exact distances; callers that use d(0) must only
    need a lower bound of it where it is ≥ ``min_gap`` (the line search's trimming keeps a superset; the near-contact
    test, d(0) < ``min_gap``, is exact)."""
    n = fv.shape[0] + ee.shape[0]
    dist, speed, first = np.empty(n), np.empty(n), np.empty(n)
    first2 = np.empty(n) if second_rescaling is not None else np.empty(0)
    keep2 = 1.0 - second_rescaling if second_rescaling is not None else 0.0
    if n:
        _bounds(
            V0, V1, faces, edges, fv, ee, 1.0 - rescaling, keep2, ADVANCES, float(min_gap), dist, speed, first, first2
        )
    return dist, speed, first, (first2 if second_rescaling is not None else None)


def refine(
    idx: np.ndarray,
    limit: float,
    V0: np.ndarray,
    V1: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    fv: np.ndarray,
    ee: np.ndarray,
    rescaling: float,
    bounds: tuple,
) -> np.ndarray:
    """Continue the conservative advancement of the candidates ``idx`` (at most REFINE_ADVANCES more distance
    evaluations each, up to fraction ``limit``), updating their ``first`` in ``bounds`` (from :func:`move_bounds`);
    returns those still below ``limit``."""
    dist, speed, first = bounds[0], bounds[1], bounds[2]
    _refine(idx, V0, V1, faces, edges, fv, ee, 1.0 - rescaling, REFINE_ADVANCES, limit, dist, speed, first)
    return idx[first[idx] < limit]


def ccd_order(first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Candidates that can come within (1 − r)·d(0) during the move (``first`` < 1, from
    :func:`move_bounds`), by increasing ``first``: (indices, their ``first``)."""
    live = np.flatnonzero(first < 1.0)
    order = live[np.argsort(first[live], kind="stable")]
    return order, first[order]


def narrow_phase_in_order(order: np.ndarray, first: np.ndarray, narrow_phase, refine=None) -> float:
    """min over the candidates of ``narrow_phase(indices)`` (a collision-free step in [0, 1] of those candidates),
    running it on batches of ``order`` (growing from FIRST_BATCH) and stopping once the next candidate cannot come
    close before the step found so far (``first`` ≥ step). ``refine(indices, step)``, if given, returns the
    candidates of a batch that can still come close before the step found so far (after a closer look)."""
    alpha, start, size = 1.0, 0, FIRST_BATCH
    while start < order.size and first[start] < alpha:
        end = min(order.size, start + size)
        idx = order[start:end]
        if refine is not None:
            idx = refine(idx, alpha)
        if idx.size:
            alpha = min(alpha, float(narrow_phase(idx)))
        start, size = end, 2 * size
    return alpha


def within(dist: np.ndarray, speed: np.ndarray, fraction: float, distance: float) -> np.ndarray:
    """Mask of the candidates that can be closer than ``distance`` somewhere on [0, ``fraction``] of the move."""
    return ~(dist - fraction * speed >= distance * (1.0 + TRIM_SLACK))  # NaN kept
