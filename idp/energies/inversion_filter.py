"""Inversion filter for line search (Smith & Schaefer 2015, as used by IDP §4.4).

Limits a Newton step x + alpha p so that no element's signed volume/area falls to eta times
its current value anywhere along the segment; with a barrier distortion energy this keeps
every iterate inversion-free.  Per element the signed volume along the step is a cubic (tets)
or quadratic (triangles) in s, whose first root in (0, 1] is found robustly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from idp._leaf import leaf_njit
from idp.threaded import run_in_parts


@leaf_njit()
def _cubic(c3: float, c2: float, c1: float, c0: float, s: float) -> float:
    return ((c3 * s + c2) * s + c1) * s + c0


@leaf_njit()
def _first_root(c3: float, c2: float, c1: float, c0: float) -> float:
    """Largest a in (0, 1] with f(s) = c3 s^3 + c2 s^2 + c1 s + c0 > 0 on [0, a) (c0 > 0).

    Stationary points of f split [0, 1] into monotone pieces; the first piece whose right
    end has f <= 0 holds the first root, which is bracketed by bisection to ~1 ulp and the
    left (still feasible) end of the bracket is returned.  Returns 1.0 when f > 0 on [0, 1].
    Near-zero leading coefficients need no special case: the stable quadratic formula for
    f' degrades gracefully to the linear root, and extra/missing breakpoints only cost an
    unnecessary split.
    """
    # breakpoints: stationary points of f in (0, 1), i.e. roots of a s^2 + b s + c
    a = 3.0 * c3
    b = 2.0 * c2
    c = c1
    r1 = 2.0
    r2 = 2.0
    disc = b * b - 4.0 * a * c
    if disc >= 0.0:
        sq = math.sqrt(disc)
        q = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
        if q != 0.0:
            r2 = c / q
            if a != 0.0:
                r1 = q / a
        elif a != 0.0:
            r1 = 0.0  # b = c = 0: double root at 0
    if r1 > r2:
        tmp = r1
        r1 = r2
        r2 = tmp
    lo = 0.0
    for piece in range(3):
        if piece == 0:
            hi = r1
        elif piece == 1:
            hi = r2
        else:
            hi = 1.0
        if not (hi > lo) or hi > 1.0:
            continue
        if _cubic(c3, c2, c1, c0, hi) <= 0.0:
            # f(lo) > 0 >= f(hi), f monotone on [lo, hi]
            for _it in range(200):
                mid = 0.5 * (lo + hi)
                if mid <= lo or mid >= hi:
                    break
                if _cubic(c3, c2, c1, c0, mid) > 0.0:
                    lo = mid
                else:
                    hi = mid
            return lo
        lo = hi
    return 1.0


@njit(cache=True, nogil=True, fastmath=False)
def _filter_kernel(
    t0: int,
    t1: int,
    x: np.ndarray,
    p: np.ndarray,
    elements: np.ndarray,
    eta: float,
    alpha: np.ndarray,
    vol0: np.ndarray,
) -> None:
    """Per element t in [t0, t1): alpha (first root in (0,1] of det(Ds + s dDs) - eta det(Ds)) and det(Ds)."""
    d = x.shape[1]
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    for t in range(t0, t1):
        i0 = elements[t, 0]
        for a in range(d):
            ia = elements[t, a + 1]
            for r in range(d):
                A[r, a] = x[ia, r] - x[i0, r]
                B[r, a] = p[ia, r] - p[i0, r]
        if d == 2:
            c0 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
            c1 = (B[0, 0] * A[1, 1] - A[0, 1] * B[1, 0]) + (A[0, 0] * B[1, 1] - B[0, 1] * A[1, 0])
            c2 = B[0, 0] * B[1, 1] - B[0, 1] * B[1, 0]
            c3 = 0.0
        else:
            # multilinear expansion of det([a0 + s b0, a1 + s b1, a2 + s b2]) by columns
            c0 = _det3(A, A, A)
            c1 = _det3(B, A, A) + _det3(A, B, A) + _det3(A, A, B)
            c2 = _det3(A, B, B) + _det3(B, A, B) + _det3(B, B, A)
            c3 = _det3(B, B, B)
        vol0[t] = c0
        if not (c0 > 0.0):
            alpha[t] = 0.0
            continue
        # normalise by c0 for scale-free tolerances
        inv = 1.0 / c0
        alpha[t] = _first_root(c3 * inv, c2 * inv, c1 * inv, 1.0 - eta)


@leaf_njit()
def _det3(C0: np.ndarray, C1: np.ndarray, C2: np.ndarray) -> float:
    """det of the 3x3 matrix whose columns 0, 1, 2 come from C0, C1, C2 respectively."""
    return (
        C0[0, 0] * (C1[1, 1] * C2[2, 2] - C2[1, 2] * C1[2, 1])
        - C1[0, 1] * (C0[1, 0] * C2[2, 2] - C2[1, 2] * C0[2, 0])
        + C2[0, 2] * (C0[1, 0] * C1[2, 1] - C1[1, 1] * C0[2, 0])
    )


def max_inversion_free_step(x: np.ndarray, p: np.ndarray, elements: np.ndarray, eta: float = 0.1) -> float:
    """Largest alpha in (0, 1] with every element's signed volume along x + s p staying
    > eta * (its volume at s = 0) for all s in [0, alpha); 1.0 if no element gets that small.

    x: (n, d) positions, p: (n, d) or flat (n*d,) step, elements: (m, d+1), d = 3 (tets) or
    2 (triangles).  The caller guarantees every element is positively oriented at s = 0
    (ValueError naming the first one otherwise).  The returned alpha is the feasible end of
    a ~1-ulp bracket of the first root, so volume(alpha) >= eta * volume(0) up to rounding.
    """
    if not 0.0 <= eta < 1.0:
        raise ValueError(f"eta must lie in [0, 1), got {eta!r}")
    x = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"x must be (n, 2) or (n, 3), got shape {x.shape}")
    p = np.ascontiguousarray(np.asarray(p, dtype=np.float64).reshape(x.shape))
    elements = np.ascontiguousarray(np.asarray(elements, dtype=np.int64))
    if elements.ndim != 2 or elements.shape[1] != x.shape[1] + 1:
        raise ValueError(f"elements must be (m, {x.shape[1] + 1}), got shape {elements.shape}")
    m = elements.shape[0]
    if m == 0:
        return 1.0
    alpha = np.empty(m)
    vol0 = np.empty(m)
    run_in_parts(
        _filter_kernel, elements.shape[0], x, p, elements, float(eta), alpha, vol0, grain=4096
    )  # ≈ 0.3 ms a part (65 ns an element)
    bad = np.flatnonzero(~(vol0 > 0.0))
    if bad.size:
        t = int(bad[0])
        raise ValueError(
            f"element {t} (vertices {elements[t].tolist()}) is not positively "
            f"oriented at the start of the step (det = {vol0[t]:.3e})"
        )
    return float(min(alpha.min(), 1.0))
