"""Numba kernels for discrete-shell bending on hinges (Grinspun et al. 2003).

A hinge is 4 vertices (x0, x1, x2, x3): the shared edge x0–x1 and the opposite vertices x2 (face 1)
and x3 (face 2).  With e = x1 - x0, a = x2 - x0, b = x3 - x0, the face normals n1 = e × a and
n2 = b × e (both the outward normals when face 1 is (x0, x1, x2) in winding order and face 2 is
(x1, x0, x3)), and the identities n1·n2 = (e·a)(e·b) - |e|²(a·b), (n1 × n2)·ê = -|e| det(e, a, b):

    θ = atan2(Y, X),   X = (e·a)(e·b) - (e·e)(a·b),   Y = -|e| e·(a × b),

the signed dihedral angle in (-π, π] (0 flat, > 0 for a convex fold, i.e. x3 below face 1).
X and Y are polynomials (times |e|), so their gradients and Hessians in u = (e, a, b) are written
directly; then ∇θ = (X∇Y - Y∇X)/r² and
∇²θ = (X∇²Y - Y∇²X + ∇Y∇Xᵀ - ∇X∇Yᵀ)/r² - 2 ∇θ (X∇X + Y∇Y)ᵀ/r², r² = X² + Y² = |n1|²|n2|²,
symmetrised (the exact result is symmetric), and pulled back linearly to the 12 vertex DOFs.
r² vanishes only for a degenerate face, so this form has no trouble at flat or sharply folded hinges.

Per hinge the energy is c (θ - θ̄)², c = k_b · 3|ē|²/(Ā1 + Ā2); gradient 2cδ∇θ and exact Hessian
2c(∇θ∇θᵀ + δ∇²θ), δ = θ - θ̄, optionally PSD-projected per 12x12 block; or its Gauss–Newton part 2c∇θ∇θᵀ
(PSD as it stands), which leaves out a term proportional to δ: near the rest angles it differs from the
projected Hessian by as little as the projection itself changes, at a tenth of the cost (no ∇²θ, no 12x12
eigenproblem).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from idp._leaf import leaf_njit
from idp.contact._psd_projection import WORK_ROWS, project_psd
from idp.threaded import run_in_parts

# u-block p (0: e, 1: a, 2: b) as a combination of the hinge vertices: u_p = Σ_v _SEL[p, v] x_v
_SEL = np.array([[-1.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 1.0]])


@leaf_njit(error_model="numpy")
def _angle(x: np.ndarray, h0: int, h1: int, h2: int, h3: int) -> float:
    """Signed dihedral angle θ of one hinge (see the module docstring)."""
    e0 = x[h1, 0] - x[h0, 0]
    e1 = x[h1, 1] - x[h0, 1]
    e2 = x[h1, 2] - x[h0, 2]
    a0 = x[h2, 0] - x[h0, 0]
    a1 = x[h2, 1] - x[h0, 1]
    a2 = x[h2, 2] - x[h0, 2]
    b0 = x[h3, 0] - x[h0, 0]
    b1 = x[h3, 1] - x[h0, 1]
    b2 = x[h3, 2] - x[h0, 2]
    ea = e0 * a0 + e1 * a1 + e2 * a2
    eb = e0 * b0 + e1 * b1 + e2 * b2
    ee = e0 * e0 + e1 * e1 + e2 * e2
    ab = a0 * b0 + a1 * b1 + a2 * b2
    V = e0 * (a1 * b2 - a2 * b1) + e1 * (a2 * b0 - a0 * b2) + e2 * (a0 * b1 - a1 * b0)
    return math.atan2(-math.sqrt(ee) * V, ea * eb - ee * ab)


@njit(cache=True, parallel=True, error_model="numpy")
def hinge_angles(x: np.ndarray, hinges: np.ndarray, out: np.ndarray) -> None:
    """out[k] = signed dihedral angle of hinge k."""
    for k in prange(hinges.shape[0]):
        out[k] = _angle(x, hinges[k, 0], hinges[k, 1], hinges[k, 2], hinges[k, 3])


@njit(cache=True, error_model="numpy")
def _put_cross(H: np.ndarray, r: int, c: int, v: np.ndarray, s: float) -> None:
    """H[r:r+3, c:c+3] = s [v]× and its transpose at H[c:c+3, r:r+3]."""
    m = np.zeros((3, 3))
    m[0, 1] = -v[2]
    m[0, 2] = v[1]
    m[1, 0] = v[2]
    m[1, 2] = -v[0]
    m[2, 0] = -v[1]
    m[2, 1] = v[0]
    for i in range(3):
        for j in range(3):
            H[r + i, c + j] = s * m[i, j]
            H[c + j, r + i] = s * m[i, j]


@njit(cache=True, nogil=True, error_model="numpy")
def _bending_chunk(
    k0: int,
    k1: int,
    x: np.ndarray,
    hinges: np.ndarray,
    rest_angle: np.ndarray,
    stiffness: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    gauss_newton: bool,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Serial body of `bending_terms` for hinges [k0, k1)."""
    e = np.empty(3)
    a = np.empty(3)
    b = np.empty(3)
    gX = np.empty(9)
    gY = np.empty(9)
    gV = np.empty(9)
    gt = np.empty(9)
    HX = np.empty((9, 9))
    HV = np.empty((9, 9))
    HY = np.empty((9, 9))
    Ht = np.empty((9, 9))
    cr = np.empty(3)
    sel = _SEL
    work = np.empty((WORK_ROWS, 12)) if (want_hess and project and not gauss_newton) else np.empty((1, 1))
    for k in range(k0, k1):
        h0 = hinges[k, 0]
        for c in range(3):
            e[c] = x[hinges[k, 1], c] - x[h0, c]
            a[c] = x[hinges[k, 2], c] - x[h0, c]
            b[c] = x[hinges[k, 3], c] - x[h0, c]
        ea = e[0] * a[0] + e[1] * a[1] + e[2] * a[2]
        eb = e[0] * b[0] + e[1] * b[1] + e[2] * b[2]
        ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
        # gV = (a×b, b×e, e×a)
        gV[0] = a[1] * b[2] - a[2] * b[1]
        gV[1] = a[2] * b[0] - a[0] * b[2]
        gV[2] = a[0] * b[1] - a[1] * b[0]
        gV[3] = b[1] * e[2] - b[2] * e[1]
        gV[4] = b[2] * e[0] - b[0] * e[2]
        gV[5] = b[0] * e[1] - b[1] * e[0]
        gV[6] = e[1] * a[2] - e[2] * a[1]
        gV[7] = e[2] * a[0] - e[0] * a[2]
        gV[8] = e[0] * a[1] - e[1] * a[0]
        V = e[0] * gV[0] + e[1] * gV[1] + e[2] * gV[2]
        ell = math.sqrt(ee)
        X = ea * eb - ee * ab
        Y = -ell * V
        theta = math.atan2(Y, X)
        delta = theta - rest_angle[k]
        cst = stiffness[k]
        energy_out[k] = cst * delta * delta
        if not (want_grad or want_hess):
            continue
        r2 = X * X + Y * Y
        for c in range(3):
            gX[c] = a[c] * eb + b[c] * ea - 2.0 * e[c] * ab
            gX[3 + c] = e[c] * eb - b[c] * ee
            gX[6 + c] = e[c] * ea - a[c] * ee
        # ∇Y = -(V ∇ℓ + ℓ ∇V), ∇ℓ = (e/ℓ, 0, 0)
        for i in range(9):
            gY[i] = -ell * gV[i]
        for c in range(3):
            gY[c] -= V * e[c] / ell
        for i in range(9):
            gt[i] = (X * gY[i] - Y * gX[i]) / r2
        if want_grad:
            s = 2.0 * cst * delta
            for v in range(4):
                for c in range(3):
                    acc = 0.0
                    for p in range(3):
                        acc += sel[p, v] * gt[3 * p + c]
                    grad_out[k, 3 * v + c] = s * acc
        if not want_hess:
            continue
        if gauss_newton:  # 2c ∇θ∇θᵀ: PSD as it stands, no second derivatives of θ, no projection
            s = 2.0 * cst
            for i in range(9):
                for j in range(i, 9):
                    v = s * gt[i] * gt[j]
                    Ht[i, j] = v
                    Ht[j, i] = v
            _lift_hinge_block(Ht, hess_out[k])
            continue
        # Hessian of X
        for i in range(9):
            for j in range(9):
                HX[i, j] = 0.0
                HV[i, j] = 0.0
        for i in range(3):
            for j in range(3):
                HX[i, j] = a[i] * b[j] + b[i] * a[j]
                eab = e[i] * b[j]
                HX[i, 3 + j] = b[i] * e[j] - 2.0 * eab
                HX[3 + j, i] = HX[i, 3 + j]
                HX[i, 6 + j] = a[i] * e[j] - 2.0 * e[i] * a[j]
                HX[6 + j, i] = HX[i, 6 + j]
                HX[3 + i, 6 + j] = e[i] * e[j]
                HX[6 + j, 3 + i] = HX[3 + i, 6 + j]
            HX[i, i] -= 2.0 * ab
            HX[i, 3 + i] += eb
            HX[3 + i, i] += eb
            HX[i, 6 + i] += ea
            HX[6 + i, i] += ea
            HX[3 + i, 6 + i] -= ee
            HX[6 + i, 3 + i] -= ee
        # Hessian of V: V_ea = -[b]x, V_eb = [a]x, V_ab = -[e]x (and transposes)
        _put_cross(HV, 0, 3, b, -1.0)
        _put_cross(HV, 0, 6, a, 1.0)
        _put_cross(HV, 3, 6, e, -1.0)
        # ∇²Y = -(∇ℓ∇Vᵀ + ∇V∇ℓᵀ + V∇²ℓ + ℓ∇²V)
        for i in range(9):
            for j in range(9):
                HY[i, j] = -ell * HV[i, j]
        for c in range(3):
            cr[c] = e[c] / ell
        for i in range(3):
            for j in range(9):
                HY[i, j] -= cr[i] * gV[j]
                HY[j, i] -= gV[j] * cr[i]
            for j in range(3):
                HY[i, j] -= V * ((1.0 if i == j else 0.0) - cr[i] * cr[j]) / ell
        for i in range(9):
            for j in range(9):
                Ht[i, j] = (X * HY[i, j] - Y * HX[i, j] + gY[i] * gX[j] - gX[i] * gY[j]) / r2 - 2.0 * gt[i] * (
                    X * gX[j] + Y * gY[j]
                ) / r2
        s = 2.0 * cst
        for i in range(9):
            for j in range(i, 9):
                v = s * (gt[i] * gt[j] + delta * 0.5 * (Ht[i, j] + Ht[j, i]))
                Ht[i, j] = v
                Ht[j, i] = v
        H = hess_out[k]
        _lift_hinge_block(Ht, H)
        if project:
            project_psd(H, np.int64(12), work)  # not a literal 12: numba would compile a project_psd of its own


@leaf_njit()
def _lift_hinge_block(Ht: np.ndarray, H: np.ndarray) -> None:  # pragma: no cover - compiled
    """The 12x12 vertex block H of a 9x9 block Ht in (e, a, b) = (x1, x2, x3) − x0: x1, x2, x3 take Ht, x0 minus
    the sum over the u-blocks."""
    for al in range(9):
        for be in range(9):
            H[3 + al, 3 + be] = Ht[al, be]
    for c in range(3):
        for j in range(9):
            H[c, 3 + j] = -(Ht[c, j] + Ht[3 + c, j] + Ht[6 + c, j])
            H[3 + j, c] = H[c, 3 + j]
    for c in range(3):
        for d in range(3):
            H[c, d] = -(H[c, 3 + d] + H[c, 6 + d] + H[c, 9 + d])


def bending_terms(
    x: np.ndarray,
    hinges: np.ndarray,
    rest_angle: np.ndarray,
    stiffness: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    gauss_newton: bool,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Fill per-hinge energy (h,), gradient (h,12) and Hessian (h,12,12) (the last two if asked).

    ``stiffness`` is c = k_b·3|ē|²/(Ā1+Ā2) per hinge.  ``gauss_newton``: the Hessian is 2c∇θ∇θᵀ (PSD; the term
    2cδ∇²θ is left out, and ``project`` has nothing to do).  Split over threads in contiguous parts
    (:func:`idp.threaded.run_in_parts`)."""
    m = hinges.shape[0]
    run_in_parts(
        _bending_chunk,
        m,
        x,
        hinges,
        rest_angle,
        stiffness,
        want_grad,
        want_hess,
        project,
        gauss_newton,
        energy_out,
        grad_out,
        hess_out,
        grain=64 if want_hess else 1024,  # ≈ 0.3 ms of work a part (idp.threaded)
    )
