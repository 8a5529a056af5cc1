"""Numba kernels for the StVK membrane on triangles embedded in 3D.

Per triangle with vertices x0, x1, x2: D = [e1 e2] = [x1 - x0, x2 - x0] (3x2), current metric
A = DᵀD, rest metric Ā, B = Ā⁻¹, M = A - Ā, Green strain E = ½ B M and

    W = w (μ tr(E²) + λ/2 (tr E)²) = w (μ/4 tr(BMBM) + λ/8 tr(BM)²),   w = rest area × thickness.

With S = ∂W/∂M = w (μ/2 BMB + λ/4 tr(BM) B) (symmetric 2x2), ∂W/∂D = 2 D S and, with C = D B (3x2),
P = C Dᵀ (3x3), the exact Hessian in the edge coordinates (e_i)_α is

    ∂²W/∂(e_i)_α ∂(e_j)_β = 2 δ_αβ S_ij + w [μ (C_αj C_βi + P_αβ B_ij) + λ C_αi C_βj],

pulled back to the 9 vertex DOFs through e1 = x1 - x0, e2 = x2 - x0.  Blocks are optionally
made PSD by ``project_psd`` (unchanged when already PSD).  Local DOF order is vertex-major.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from idp.contact._psd_projection import WORK_ROWS, project_psd
from idp.threaded import run_in_parts

# edge i (0: x1-x0, 1: x2-x0) as a combination of the vertices: e_i = Σ_a _SEL[a, i] x_a
_SEL = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])


@njit(cache=True, nogil=True, error_model="numpy")
def _membrane_chunk(
    t0: int,
    t1: int,
    x: np.ndarray,
    tris: np.ndarray,
    rest_metric: np.ndarray,
    rest_metric_inv: np.ndarray,
    weight: np.ndarray,
    mu: np.ndarray,
    lam: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Serial body of `membrane_terms` for triangles [t0, t1)."""
    D = np.empty((3, 2))
    M = np.empty((2, 2))
    BM = np.empty((2, 2))
    BMB = np.empty((2, 2))
    S = np.empty((2, 2))
    C = np.empty((3, 2))
    P = np.empty((3, 3))
    He = np.empty((6, 6))
    sel = _SEL
    work = np.empty((WORK_ROWS, 12)) if (want_hess and project) else np.empty((1, 1))
    for t in range(t0, t1):
        i0 = tris[t, 0]
        for c in range(3):
            D[c, 0] = x[tris[t, 1], c] - x[i0, c]
            D[c, 1] = x[tris[t, 2], c] - x[i0, c]
        for i in range(2):
            for j in range(2):
                s = 0.0
                for c in range(3):
                    s += D[c, i] * D[c, j]
                M[i, j] = s - rest_metric[t, i, j]
        B = rest_metric_inv[t]
        for i in range(2):
            for j in range(2):
                BM[i, j] = B[i, 0] * M[0, j] + B[i, 1] * M[1, j]
        for i in range(2):
            for j in range(2):
                BMB[i, j] = BM[i, 0] * B[0, j] + BM[i, 1] * B[1, j]
        tr = BM[0, 0] + BM[1, 1]
        trsq = BM[0, 0] * BM[0, 0] + 2.0 * BM[0, 1] * BM[1, 0] + BM[1, 1] * BM[1, 1]
        w = weight[t]
        m_ = mu[t]
        l_ = lam[t]
        energy_out[t] = w * (0.25 * m_ * trsq + 0.125 * l_ * tr * tr)
        if not (want_grad or want_hess):
            continue
        for i in range(2):
            for j in range(2):
                S[i, j] = w * (0.5 * m_ * BMB[i, j] + 0.25 * l_ * tr * B[i, j])
        if want_grad:
            for c in range(3):
                g1 = 2.0 * (D[c, 0] * S[0, 0] + D[c, 1] * S[1, 0])
                g2 = 2.0 * (D[c, 0] * S[0, 1] + D[c, 1] * S[1, 1])
                grad_out[t, c] = -g1 - g2
                grad_out[t, 3 + c] = g1
                grad_out[t, 6 + c] = g2
        if not want_hess:
            continue
        for c in range(3):
            for i in range(2):
                C[c, i] = D[c, 0] * B[0, i] + D[c, 1] * B[1, i]
        for a in range(3):
            for b in range(3):
                P[a, b] = C[a, 0] * D[b, 0] + C[a, 1] * D[b, 1]
        for i in range(2):
            for al in range(3):
                r = 3 * i + al
                for j in range(2):
                    for be in range(3):
                        v = w * (m_ * (C[al, j] * C[be, i] + P[al, be] * B[i, j]) + l_ * C[al, i] * C[be, j])
                        if al == be:
                            v += 2.0 * S[i, j]
                        He[r, 3 * j + be] = v
        H = hess_out[t]
        for a in range(3):
            for b in range(3):
                for al in range(3):
                    for be in range(3):
                        v = 0.0
                        for i in range(2):
                            sa = sel[a, i]
                            if sa == 0.0:
                                continue
                            for j in range(2):
                                sb = sel[b, j]
                                if sb != 0.0:
                                    v += sa * sb * He[3 * i + al, 3 * j + be]
                        H[3 * a + al, 3 * b + be] = v
        if project:
            # a literal 9 on purpose: numba compiles a projection for it (≈ 7 s once) that runs 7.6 % faster than
            # the run-time-k one the barrier and bending share (docs/benchmarks.md, "Time to first result")
            project_psd(H, 9, work)


def membrane_terms(
    x: np.ndarray,
    tris: np.ndarray,
    rest_metric: np.ndarray,
    rest_metric_inv: np.ndarray,
    weight: np.ndarray,
    mu: np.ndarray,
    lam: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Fill per-triangle energy (m,), gradient (m,9) and Hessian (m,9,9) (the last two if asked).

    Split over threads in contiguous parts (:func:`idp.threaded.run_in_parts`); each triangle writes only its own
    output rows."""
    m = tris.shape[0]
    run_in_parts(
        _membrane_chunk,
        m,
        x,
        tris,
        rest_metric,
        rest_metric_inv,
        weight,
        mu,
        lam,
        want_grad,
        want_hess,
        project,
        energy_out,
        grad_out,
        hess_out,
        grain=256 if want_hess else 4096,  # ≈ 0.3 ms of work a part (idp.threaded)
    )
