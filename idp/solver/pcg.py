"""Preconditioned conjugate gradients for H x = b with a factorised SPD majorant M ⪰ H as preconditioner.

Used for the exact Newton direction after the contact pattern folded a few couplings into the diagonal
(:mod:`idp.solver.contact_pattern`): H = M + K with K supported on the folded vertices, so M⁻¹H is the
identity plus a low-rank term and CG started from M's own solution needs about as many iterations as K
has significant eigenvalues — far cheaper than a new ordering, symbolic analysis and factorisation.
Every CG iterate started from M⁻¹b is a descent direction of the quadratic model (its value only
decreases from that of M⁻¹b, which is negative because M ⪰ H).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["pcg_from_majorant"]


def pcg_from_majorant(
    matvec: Callable[[np.ndarray], np.ndarray],
    precondition: Callable[[np.ndarray], np.ndarray],
    b: np.ndarray,
    x0: np.ndarray,
    rtol: float,
    max_iterations: int,
) -> tuple[np.ndarray, int, bool]:
    """Solve ``matvec(x) = b`` from ``x0 = precondition(b)``; returns (x, iterations, converged).

    Stops when ‖r‖_{M⁻¹} ≤ rtol·‖b‖_{M⁻¹} (both norms from the preconditioner, so the test is scale-free).
    Reports non-convergence (instead of raising) when the cap is hit or a non-positive curvature shows
    that H is not positive definite."""
    x = np.array(x0, dtype=float, copy=True)
    r = b - matvec(x)
    z = precondition(r)
    rz = float(r @ z)
    target = rtol * rtol * max(float(b @ x0), 0.0)
    p = z
    for k in range(max_iterations + 1):
        if rz <= target:
            return x, k, True
        if k == max_iterations:
            break
        Ap = matvec(p)
        pAp = float(p @ Ap)
        if not pAp > 0.0:
            return x, k, False
        a = rz / pAp
        x += a * p
        r -= a * Ap
        z = precondition(r)
        rz_new = float(r @ z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, max_iterations, False
