"""Small dense linear algebra shared by the numba kernels (elastic energies, contact PSD projection)."""

from __future__ import annotations

import math

import numpy as np

from idp._leaf import leaf_njit


@leaf_njit(error_model="numpy")
def symmetric_eigen_jacobi(S: np.ndarray, d: int, Q: np.ndarray, lam: np.ndarray) -> None:
    """Eigen-decomposition of a symmetric d x d matrix by cyclic Jacobi: S = Q diag(lam) Q^T.

    S is overwritten (ends diagonal)."""
    for r in range(d):
        for c in range(d):
            Q[r, c] = 1.0 if r == c else 0.0
    for _sweep in range(50):
        off = 0.0
        tot = 0.0
        for r in range(d):
            for c in range(d):
                tot += S[r, c] * S[r, c]
                if r != c:
                    off += S[r, c] * S[r, c]
        if off == 0.0 or off <= 1e-32 * tot:
            break
        for p in range(d - 1):
            for q in range(p + 1, d):
                apq = S[p, q]
                if apq == 0.0:
                    continue
                theta = (S[q, q] - S[p, p]) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                cs = 1.0 / math.sqrt(t * t + 1.0)
                sn = t * cs
                for r in range(d):  # columns: S J
                    sp = S[r, p]
                    sq = S[r, q]
                    S[r, p] = cs * sp - sn * sq
                    S[r, q] = sn * sp + cs * sq
                for r in range(d):  # rows: J^T (S J)
                    sp = S[p, r]
                    sq = S[q, r]
                    S[p, r] = cs * sp - sn * sq
                    S[q, r] = sn * sp + cs * sq
                for r in range(d):
                    qp = Q[r, p]
                    qq = Q[r, q]
                    Q[r, p] = cs * qp - sn * qq
                    Q[r, q] = sn * qp + cs * qq
    for i in range(d):
        lam[i] = S[i, i]
