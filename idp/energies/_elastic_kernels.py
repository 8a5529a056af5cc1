"""Per-element kernels for simplex distortion energies.

Models: neo-Hookean and symmetric Dirichlet (barriers, +inf for det F <= 0), ARAP and
St. Venant-Kirchhoff (non-barrier: finite for every F, inverted elements included).

For element t with local vertices x_0..x_d: F = Ds Dm^{-1}, Ds = [x_1-x_0, ..., x_d-x_0],
energy v_t Psi(F), gradient v_t dPsi/dF pulled back to the d+1 nodes, and the Hessian built
from the analytic eigensystem of an isotropic energy written in signed singular values
(scaling block + per-pair flip/twist modes), each eigenvalue optionally clamped at 0 so the
element block is PSD without a (d+1)d x (d+1)d eigen-decomposition.

Eigensystem (Smith et al. 2019, "Analytic eigensystems for isotropic distortion energies"):
with F = U diag(s) V^T (rotation-variant SVD, s_d signed) and psi_i = dpsi/ds_i, the d x d
scaling block is S = d^2 psi / ds^2 on the modes U diag(q) V^T, and each pair i < j has a flip
mode U (e_i e_j^T + e_j e_i^T) V^T / sqrt 2 with eigenvalue (psi_i - psi_j) / (s_i - s_j) and a
twist mode U (e_i e_j^T - e_j e_i^T) V^T / sqrt 2 with eigenvalue (psi_i + psi_j) / (s_i + s_j).
Per model, in closed forms that stay finite at s_i = s_j:

* NH (mu, lambda; c = mu - lambda ln J): S_ii = mu + (c + lambda)/s_i^2, S_ij = lambda/(s_i s_j),
  flip = mu + c/(s_i s_j), twist = mu - c/(s_i s_j).
* SD (weight w): S_ii = 2w(1 + 3/s_i^4), S_ij = 0, flip = 2w(1 + (s_i^2 + s_i s_j + s_j^2)/(s_i s_j)^3),
  twist = 2w(1 - (s_i^2 - s_i s_j + s_j^2)/(s_i s_j)^3).
* ARAP, psi = mu sum (s_i - 1)^2 = mu ||F - R||^2 (R = U V^T): S = 2 mu I, flip = 2 mu,
  twist = 2 mu (1 - 2/(s_i + s_j)).  s_i + s_j = 0 (an inverted element whose two smallest
  signed singular values cancel) is where R jumps and the exact Hessian does not exist; the sum is
  floored at ``ARAP_TWIST_FLOOR`` so the exact block stays finite (hugely negative), and the
  projected twist eigenvalue is 0 whenever s_i + s_j <= 2 anyway.
* StVK, psi = mu ||E||^2 + lambda/2 (tr E)^2, E = (F^T F - I)/2; with h = lambda (|F|^2 - d)/2:
  S_ii = mu (3 s_i^2 - 1) + h + lambda s_i^2, S_ij = lambda s_i s_j,
  flip = mu (s_i^2 + s_i s_j + s_j^2 - 1) + h, twist = mu (s_i^2 - s_i s_j + s_j^2 - 1) + h.

Local DOF order of an element block: [x0_0, .., x0_{d-1}, x1_0, ...] (vertex-major).

`element_terms` (per-element outputs) and `element_terms_scatter` (added straight into the Newton matrix) are the
hot path, both through one compiled `_element_pass` (chunks of elements or parts of the vertex rows, split
over threads by `idp.threaded.run_in_parts`; scratch arrays allocated once per chunk); `element_terms_reference`
is a plain vectorised numpy version built along a different route (explicit dF/dx matrix, LAPACK SVD/eigh) kept
for tests.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from idp._leaf import leaf_njit
from idp._small_dense import symmetric_eigen_jacobi
from idp.energies._pnorm_kernels import power_tail, rest_value, sigma_gradient
from idp.threaded import run_in_parts

NEO_HOOKEAN = 0
SYMMETRIC_DIRICHLET = 1
ARAP = 2
STVK = 3

#: Floor of s_i + s_j in the ARAP twist eigenvalue 2 mu (1 - 2/(s_i + s_j)) (see the module docstring).
ARAP_TWIST_FLOOR = 1e-12

#: Elements per parallel work item; scratch arrays are allocated once per chunk.
CHUNK = 64

_SQRT_HALF = 1.0 / math.sqrt(2.0)


# --------------------------------------------------------------------------------------
# small dense helpers (d = 2 or 3)
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def _det(M: np.ndarray, d: int) -> float:
    """Determinant of the leading d x d block."""
    if d == 2:
        return M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return (
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )


@leaf_njit(error_model="numpy")
def _inverse(M: np.ndarray, d: int, J: float, out: np.ndarray) -> None:
    """out = M^{-1} via the adjugate (J = det M, nonzero)."""
    s = 1.0 / J
    if d == 2:
        out[0, 0] = M[1, 1] * s
        out[0, 1] = -M[0, 1] * s
        out[1, 0] = -M[1, 0] * s
        out[1, 1] = M[0, 0] * s
        return
    out[0, 0] = (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) * s
    out[0, 1] = (M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]) * s
    out[0, 2] = (M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]) * s
    out[1, 0] = (M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]) * s
    out[1, 1] = (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]) * s
    out[1, 2] = (M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]) * s
    out[2, 0] = (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]) * s
    out[2, 1] = (M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]) * s
    out[2, 2] = (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]) * s


@leaf_njit(error_model="numpy")
def _rotation_svd(F: np.ndarray, d: int, U: np.ndarray, sig: np.ndarray, V: np.ndarray, A: np.ndarray) -> None:
    """F = U diag(sig) V^T with det U = det V = +1, |sig| descending, sign(sig[d-1]) = sign(det F).

    One-sided (Hestenes) Jacobi on the columns of A = F V, which gives singular values to
    high relative accuracy; U is completed by orthogonalisation / cross product so it is a
    rotation even for rank-deficient F.  A is scratch.
    """
    for r in range(d):
        for c in range(d):
            A[r, c] = F[r, c]
            V[r, c] = 1.0 if r == c else 0.0
    sweep = 0
    rotated = True
    while rotated and sweep < 40:  # until a sweep rotates nothing (a condition, not ``break``: numba then prunes
        # the atomic reference counts of the array arguments, ≈ 10 % of the element kernel on 2 threads)
        rotated = False
        for p in range(d - 1):
            for q in range(p + 1, d):
                alpha = 0.0
                beta = 0.0
                gamma = 0.0
                for r in range(d):
                    alpha += A[r, p] * A[r, p]
                    beta += A[r, q] * A[r, q]
                    gamma += A[r, p] * A[r, q]
                if gamma * gamma <= 1e-30 * (alpha * beta):  # |γ| ≤ 1e-15·√(αβ), without the root
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                if abs(zeta) > 1e150:
                    t = 0.5 / zeta
                else:
                    t = 1.0 / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                    if zeta < 0.0:
                        t = -t
                cs = 1.0 / math.sqrt(1.0 + t * t)
                sn = cs * t
                for r in range(d):
                    ap = A[r, p]
                    aq = A[r, q]
                    A[r, p] = cs * ap - sn * aq
                    A[r, q] = sn * ap + cs * aq
                    vp = V[r, p]
                    vq = V[r, q]
                    V[r, p] = cs * vp - sn * vq
                    V[r, q] = sn * vp + cs * vq
        sweep += 1
    for c in range(d):
        nrm = 0.0
        for r in range(d):
            nrm += A[r, c] * A[r, c]
        sig[c] = math.sqrt(nrm)
    # sort columns by descending norm (selection sort, d <= 3)
    for i in range(d - 1):
        best = i
        for j in range(i + 1, d):
            if sig[j] > sig[best]:
                best = j
        if best != i:
            tmp = sig[i]
            sig[i] = sig[best]
            sig[best] = tmp
            for r in range(d):
                tmp = A[r, i]
                A[r, i] = A[r, best]
                A[r, best] = tmp
                # a swap flips det V; negate one column to keep a rotation
                tmp = V[r, i]
                V[r, i] = V[r, best]
                V[r, best] = -tmp
                A[r, best] = -A[r, best]
    # U: first columns from A, the last one completes a right-handed frame
    if sig[0] > 0.0:
        for r in range(d):
            U[r, 0] = A[r, 0] / sig[0]
    else:
        for r in range(d):
            U[r, 0] = 1.0 if r == 0 else 0.0
    if d == 2:
        U[0, 1] = -U[1, 0]
        U[1, 1] = U[0, 0]
        sig[1] = U[0, 1] * A[0, 1] + U[1, 1] * A[1, 1]
        return
    # d == 3: u1 = normalised component of a1 orthogonal to u0
    dot = U[0, 0] * A[0, 1] + U[1, 0] * A[1, 1] + U[2, 0] * A[2, 1]
    w0 = A[0, 1] - dot * U[0, 0]
    w1 = A[1, 1] - dot * U[1, 0]
    w2 = A[2, 1] - dot * U[2, 0]
    nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if nw <= 1e-300 or nw < 1e-8 * sig[1]:
        # a1 ~ 0: any unit vector orthogonal to u0 will do
        ax = 0
        if abs(U[1, 0]) < abs(U[ax, 0]):
            ax = 1
        if abs(U[2, 0]) < abs(U[ax, 0]):
            ax = 2
        e0 = 1.0 if ax == 0 else 0.0
        e1 = 1.0 if ax == 1 else 0.0
        e2 = 1.0 if ax == 2 else 0.0
        dot = U[ax, 0]
        w0 = e0 - dot * U[0, 0]
        w1 = e1 - dot * U[1, 0]
        w2 = e2 - dot * U[2, 0]
        nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    U[0, 1] = w0 / nw
    U[1, 1] = w1 / nw
    U[2, 1] = w2 / nw
    sig[1] = U[0, 1] * A[0, 1] + U[1, 1] * A[1, 1] + U[2, 1] * A[2, 1]
    U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
    U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
    U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
    sig[2] = U[0, 2] * A[0, 2] + U[1, 2] * A[1, 2] + U[2, 2] * A[2, 2]


@leaf_njit(error_model="numpy")
def _sigma_eigensystem(
    model: int,
    a: float,
    b: float,
    sig: np.ndarray,
    lnJ: float,
    d: int,
    S: np.ndarray,
    flip: np.ndarray,
    twist: np.ndarray,
) -> None:
    """S = d^2 psi / d sigma^2; flip[i,j] = (psi_i - psi_j)/(s_i - s_j), twist[i,j] = (psi_i + psi_j)/(s_i + s_j).

    Closed forms that stay finite at s_i = s_j (module docstring).  NH, StVK: a = mu, b = lambda;
    SD: a = weight w; ARAP: a = mu.  lnJ is used by NH only.
    """
    if model == ARAP:
        w2 = 2.0 * a
        for i in range(d):
            for j in range(d):
                if i == j:
                    S[i, i] = w2
                else:
                    S[i, j] = 0.0
                    flip[i, j] = w2
                    twist[i, j] = w2 * (1.0 - 2.0 / max(sig[i] + sig[j], ARAP_TWIST_FLOOR))
    elif model == STVK:
        mu = a
        la = b
        i2 = 0.0
        for i in range(d):
            i2 += sig[i] * sig[i]
        h = 0.5 * la * (i2 - d)
        for i in range(d):
            si = sig[i]
            for j in range(d):
                sj = sig[j]
                if i == j:
                    S[i, i] = mu * (3.0 * si * si - 1.0) + h + la * si * si
                else:
                    S[i, j] = la * si * sj
                    flip[i, j] = mu * (si * si + si * sj + sj * sj - 1.0) + h
                    twist[i, j] = mu * (si * si - si * sj + sj * sj - 1.0) + h
    elif model == NEO_HOOKEAN:
        mu = a
        la = b
        cc = mu - la * lnJ
        for i in range(d):
            for j in range(d):
                sij = sig[i] * sig[j]
                if i == j:
                    S[i, i] = mu + (cc + la) / sij
                else:
                    S[i, j] = la / sij
                    flip[i, j] = mu + cc / sij
                    twist[i, j] = mu - cc / sij
    else:
        w2 = 2.0 * a
        for i in range(d):
            si = sig[i]
            for j in range(d):
                if i == j:
                    S[i, i] = w2 * (1.0 + 3.0 / (si * si * si * si))
                else:
                    sj = sig[j]
                    S[i, j] = 0.0
                    p3 = (si * sj) ** 3
                    flip[i, j] = w2 * (1.0 + (si * si + si * sj + sj * sj) / p3)
                    twist[i, j] = w2 * (1.0 - (si * si - si * sj + sj * sj) / p3)


@leaf_njit(error_model="numpy")
def _is_pd(S: np.ndarray, d: int) -> bool:
    """Symmetric d x d S positive definite (all leading principal minors > 0)."""
    if not (S[0, 0] > 0.0):
        return False
    m2 = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    if not (m2 > 0.0):
        return False
    if d == 2:
        return True
    return _det(S, d) > 0.0  # d (= 3 here), not a literal 3: one compiled _det serves every caller


@leaf_njit(error_model="numpy")
def _add_mode(H: np.ndarray, g: np.ndarray, coef: float, k: int) -> None:
    """H[upper] += coef g g^T (upper triangle only)."""
    for i in range(k):
        gi = coef * g[i]
        if gi == 0.0:
            continue
        for j in range(i, k):
            H[i, j] += gi * g[j]


@leaf_njit(error_model="numpy")
def _pull_back(P: np.ndarray, d: int, g: np.ndarray) -> None:
    """g = dF/dx^T : P for P already multiplied by Dm^{-T} (columns -> nodes 1..d, node 0 = -sum)."""
    for r in range(d):
        acc = 0.0
        for a in range(d):
            g[(a + 1) * d + r] = P[r, a]
            acc += P[r, a]
        g[r] = -acc


@leaf_njit(error_model="numpy")
def _hessian3(
    U, V, S, flip, twist, dm_inv, t, v, project, Ya, Sp, Q, lamS, L, R, Hr, hess_out, o
) -> None:  # pragma: no cover
    """H (12 x 12) = v·(dF/dx)ᵀ (Σ modes λ q qᵀ) (dF/dx) of one tetrahedron, eigenvalues clamped at 0 if ``project``.

    The same sum as the general path, organised for d = 3 (constant loop bounds): every mode is pulled back to
    the 9 DOFs of nodes 1..3 only (node 0's rows are minus the sum of the others', by translation invariance),
    the scaling block enters as Σ_il S⁺_il d_i d_lᵀ (S⁺ = S, or S with its eigenvalues clamped when it is not
    PD), and the 9 × 9 block is one product of 9 left and 9 right vectors. ``dm_inv[t]`` = Dm⁻¹ of the element,
    the result goes to ``hess_out[o]``; both are indexed in place (a row view ``dm_inv[t]`` costs two atomic
    reference-count updates on the array both threads share: ≈ 10 % of the element kernel's time).
    Ya, Sp, Q (3 x 3), lamS (3), L, R, Hr (9 x 9) are scratch."""
    # Y = Dm^{-1} V: the pull-back of U M Vᵀ to node a (1..3), coordinate s is Σ_ij U[s,i] M[i,j] Y[a-1,j]
    for a in range(3):
        for j in range(3):
            Ya[a, j] = dm_inv[t, a, 0] * V[0, j] + dm_inv[t, a, 1] * V[1, j] + dm_inv[t, a, 2] * V[2, j]
    # clamped scaling block S⁺
    # np.int64(3), not a literal 3: the _is_pd / symmetric_eigen_jacobi the general path compiles (one each)
    if project and not _is_pd(S, np.int64(3)):
        for i in range(3):
            for j in range(3):
                Sp[i, j] = S[i, j]
        symmetric_eigen_jacobi(Sp, np.int64(3), Q, lamS)
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for l in range(3):
                    lam = lamS[l]
                    if lam > 0.0:
                        acc += Q[i, l] * lam * Q[j, l]
                Sp[i, j] = acc
    else:
        for i in range(3):
            for j in range(3):
                Sp[i, j] = S[i, j]
    # scaling modes: L[i] = d_i (d_i[3a+s] = Y[a,i] U[s,i]), R[i] = v Σ_l S⁺[i,l] d_l
    for i in range(3):
        for a in range(3):
            for s in range(3):
                L[i, 3 * a + s] = Ya[a, i] * U[s, i]
    for i in range(3):
        for p in range(9):
            R[i, p] = v * (Sp[i, 0] * L[0, p] + Sp[i, 1] * L[1, p] + Sp[i, 2] * L[2, p])
    # flip / twist modes of each pair (i, j): (U e_i e_jᵀ Vᵀ ± U e_j e_iᵀ Vᵀ)/√2
    k = 3
    for i in range(2):
        for j in range(i + 1, 3):
            lf = flip[i, j]
            lt = twist[i, j]
            if project:
                lf = max(lf, 0.0)
                lt = max(lt, 0.0)
            for a in range(3):
                for s in range(3):
                    x1 = Ya[a, j] * U[s, i]
                    x2 = Ya[a, i] * U[s, j]
                    gp = _SQRT_HALF * (x1 + x2)
                    gm = _SQRT_HALF * (x1 - x2)
                    L[k, 3 * a + s] = gp
                    R[k, 3 * a + s] = v * lf * gp
                    L[k + 1, 3 * a + s] = gm
                    R[k + 1, 3 * a + s] = v * lt * gm
            k += 2
    # Hr = Lᵀ R (symmetric: upper triangle, then mirrored)
    for p in range(9):
        for q in range(p, 9):
            acc = 0.0
            for m in range(9):
                acc += L[m, p] * R[m, q]
            Hr[p, q] = acc
            Hr[q, p] = acc
    # expand to the 4 nodes: node 0 = −(nodes 1 + 2 + 3)
    for p in range(9):
        for q in range(9):
            hess_out[o, 3 + p, 3 + q] = Hr[p, q]
    for s in range(3):
        for q in range(9):
            c = -(Hr[s, q] + Hr[3 + s, q] + Hr[6 + s, q])
            hess_out[o, s, 3 + q] = c
            hess_out[o, 3 + q, s] = c
    for s in range(3):
        for s2 in range(s, 3):
            c = -(hess_out[o, s, 3 + s2] + hess_out[o, s, 6 + s2] + hess_out[o, s, 9 + s2])
            hess_out[o, s, s2] = c
            hess_out[o, s2, s] = c


# --------------------------------------------------------------------------------------
# main kernel
# --------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _element_chunk(
    q_begin: int,
    q_end: int,
    ids: np.ndarray,
    out_shift: int,
    x: np.ndarray,
    elements: np.ndarray,
    dm_inv: np.ndarray,
    volumes: np.ndarray,
    model: int,
    param_a: np.ndarray,
    param_b: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    power: float,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Serial body of `element_terms` for elements [q_begin, q_end) (scratch allocated once): element
    t = q, or t = ids[q] when ``ids`` is not empty; its outputs go to row q − out_shift."""
    d = x.shape[1]
    k = (d + 1) * d
    barrier = model == NEO_HOOKEAN or model == SYMMETRIC_DIRICHLET
    Ds = np.empty((d, d))
    F = np.empty((d, d))
    Fi = np.empty((d, d))
    P = np.empty((d, d))
    PW = np.empty((d, d))
    U = np.empty((d, d))
    V = np.empty((d, d))
    A = np.empty((d, d))
    Eg = np.empty((d, d))
    W = np.empty((d, d))
    S = np.empty((d, d))
    Q = np.empty((d, d))
    flip = np.zeros((d, d))
    twist = np.zeros((d, d))
    sig = np.empty(d)
    dpsi = np.empty(d)
    lamS = np.empty(d)
    pnorm = power != 1.0
    g = np.empty(k)
    Gs = np.empty((d, k))
    Sp = np.empty((3, 3))
    Ya = np.empty((3, 3))
    L9 = np.empty((9, 9))
    R9 = np.empty((9, 9))
    Hr9 = np.empty((9, 9))
    for q in range(q_begin, q_end):
        t = ids[q] if ids.size else q
        o = q - out_shift
        v = volumes[t]
        i0 = elements[t, 0]
        for a in range(d):
            ia = elements[t, a + 1]
            for r in range(d):
                Ds[r, a] = x[ia, r] - x[i0, r]
        for r in range(d):
            for c in range(d):
                acc = 0.0
                for a in range(d):
                    acc += Ds[r, a] * dm_inv[t, a, c]
                F[r, c] = acc
        J = _det(F, d)
        if barrier and not (J > 0.0):
            energy_out[o] = np.inf
            if want_grad:
                for i in range(k):
                    grad_out[o, i] = np.nan
            if want_hess:
                for i in range(k):
                    for j in range(k):
                        hess_out[o, i, j] = np.nan
            continue
        pa = param_a[t]
        pb = param_b[t]
        lnJ = 0.0
        have_svd = False
        trE = 0.0
        if barrier:
            _inverse(F, d, J, Fi)
            lnJ = math.log(J)
            nF = 0.0
            for r in range(d):
                for c in range(d):
                    nF += F[r, c] * F[r, c]
            if model == NEO_HOOKEAN:
                psi = 0.5 * pa * (nF - d) - pa * lnJ + 0.5 * pb * lnJ * lnJ
            else:
                nFi = 0.0
                for r in range(d):
                    for c in range(d):
                        nFi += Fi[r, c] * Fi[r, c]
                psi = pa * (nF + nFi - 2.0 * d)
        elif model == ARAP:
            # mu ||F - R||^2 = mu sum (s_i - 1)^2 with signed singular values
            _rotation_svd(F, d, U, sig, V, A)
            have_svd = True
            psi = 0.0
            for i in range(d):
                psi += (sig[i] - 1.0) * (sig[i] - 1.0)
            psi *= pa
        else:
            # StVK: Eg = (F^T F - I) / 2
            nE = 0.0
            for r in range(d):
                for c in range(d):
                    acc = 0.0
                    for a in range(d):
                        acc += F[a, r] * F[a, c]
                    if r == c:
                        acc -= 1.0
                    Eg[r, c] = 0.5 * acc
                    nE += Eg[r, c] * Eg[r, c]
                trE += Eg[r, r]
            psi = pa * nE + 0.5 * pb * trE * trE
        # p-norm (paper eq. 9, see _pnorm_kernels): energy v Ψ̂(I) g(ρ)/p, stress × c1, σ-Hessian c1 S + c2 ψψᵀ
        c1 = 1.0
        c2 = 0.0
        if pnorm:
            psi0 = rest_value(model, pa, d)
            gv, g1, g2 = power_tail((psi + psi0) / psi0, power)
            energy_out[o] = v * psi0 * gv / power
            c1 = g1 / power
            c2 = g2 / (power * psi0)
        else:
            energy_out[o] = v * psi
        if want_grad:
            # P = dPsi/dF using F^{-T}[r,c] = Fi[c,r]
            if model == NEO_HOOKEAN:
                cc = pb * lnJ - pa
                for r in range(d):
                    for c in range(d):
                        P[r, c] = pa * F[r, c] + cc * Fi[c, r]
            elif model == SYMMETRIC_DIRICHLET:
                # P = 2w (F - F^{-T} F^{-1} F^{-T}); (F^{-T}F^{-1}F^{-T})[r,c] = sum Fi[a,r] Fi[a,b] Fi[c,b]
                for r in range(d):
                    for c in range(d):
                        acc = 0.0
                        for a2 in range(d):
                            for b2 in range(d):
                                acc += Fi[a2, r] * Fi[a2, b2] * Fi[c, b2]
                        P[r, c] = 2.0 * pa * (F[r, c] - acc)
            elif model == ARAP:
                # P = 2 mu (F - U V^T)
                for r in range(d):
                    for c in range(d):
                        acc = 0.0
                        for a2 in range(d):
                            acc += U[r, a2] * V[c, a2]
                        P[r, c] = 2.0 * pa * (F[r, c] - acc)
            else:
                # StVK: P = F (2 mu E + lambda tr(E) I)
                for r in range(d):
                    for c in range(d):
                        acc = 0.0
                        for a2 in range(d):
                            acc += F[r, a2] * Eg[a2, c]
                        P[r, c] = 2.0 * pa * acc + pb * trE * F[r, c]
            # PW = v c1 P Dm^{-T}
            vc1 = v * c1
            for r in range(d):
                for a in range(d):
                    acc = 0.0
                    for c in range(d):
                        acc += P[r, c] * dm_inv[t, a, c]
                    PW[r, a] = vc1 * acc
            _pull_back(PW, d, g)
            for i in range(k):
                grad_out[o, i] = g[i]
        if want_hess:
            if not have_svd:
                _rotation_svd(F, d, U, sig, V, A)
            _sigma_eigensystem(model, pa, pb, sig, lnJ, d, S, flip, twist)
            if pnorm:
                sigma_gradient(model, pa, pb, sig, lnJ, d, dpsi)
                for i in range(d):
                    for j in range(d):
                        S[i, j] = c1 * S[i, j] + c2 * dpsi[i] * dpsi[j]
                        flip[i, j] *= c1
                        twist[i, j] *= c1
            if d == 3:
                _hessian3(U, V, S, flip, twist, dm_inv, t, v, project, Ya, Sp, Q, lamS, L9, R9, Hr9, hess_out, o)
                continue
            H = hess_out[o]
            for i in range(k):
                for j in range(k):
                    H[i, j] = 0.0
            direct = (not project) or _is_pd(S, d)
            if not direct:
                symmetric_eigen_jacobi(S, d, Q, lamS)
            # W = V^T Dm^{-T}: mode U M V^T maps to P = U M W
            for j in range(d):
                for a in range(d):
                    acc = 0.0
                    for c in range(d):
                        acc += V[c, j] * dm_inv[t, a, c]
                    W[j, a] = acc
            if direct:
                # scaling block needs no clamping: H += v sum_ij S_ij g_i g_j^T with g_i
                # the pull-back of U e_i e_i^T V^T (skips the d x d eigen-decomposition)
                for i in range(d):
                    for r in range(d):
                        for a in range(d):
                            PW[r, a] = U[r, i] * W[i, a]
                    _pull_back(PW, d, g)
                    for j in range(k):
                        Gs[i, j] = g[j]
                for i in range(d):
                    for j in range(k):
                        acc = 0.0
                        for l in range(d):
                            acc += S[i, l] * Gs[l, j]
                        g[j] = v * acc
                    for a in range(k):
                        ga = Gs[i, a]
                        if ga == 0.0:
                            continue
                        for b in range(a, k):
                            H[a, b] += ga * g[b]
            # scaling modes U diag(q) V^T of the clamped eigen-decomposition of S
            for l in range(d):
                if direct:
                    break
                lam = lamS[l]
                if project and lam < 0.0:
                    lam = 0.0
                if lam == 0.0:
                    continue
                for r in range(d):
                    for a in range(d):
                        acc = 0.0
                        for l2 in range(d):
                            acc += U[r, l2] * Q[l2, l] * W[l2, a]
                        PW[r, a] = acc
                _pull_back(PW, d, g)
                _add_mode(H, g, v * lam, k)
            # flip / twist modes per pair
            for i in range(d - 1):
                for j in range(i + 1, d):
                    for mode in range(2):
                        if mode == 0:
                            lam = flip[i, j]
                            sgn = 1.0
                        else:
                            lam = twist[i, j]
                            sgn = -1.0
                        if project and lam < 0.0:
                            lam = 0.0
                        if lam == 0.0:
                            continue
                        for r in range(d):
                            for a in range(d):
                                PW[r, a] = _SQRT_HALF * (U[r, i] * W[j, a] + sgn * U[r, j] * W[i, a])
                        _pull_back(PW, d, g)
                        _add_mode(H, g, v * lam, k)
            for i in range(k):
                for j in range(i):
                    H[i, j] = H[j, i]


@njit(cache=True, error_model="numpy")
def _scatter_part(
    p,
    x,
    elements,
    dm_inv,
    volumes,
    model,
    param_a,
    param_b,
    project,
    power,
    owner,
    part_ptr,
    part_elements,
    base,
    stride,
    weight,
    data,
    grad,
):  # pragma: no cover
    """Part p of :func:`element_terms_scatter` (one thread's vertex rows)."""
    d = x.shape[1]
    nv = elements.shape[1]
    k = nv * d
    e_buf = np.empty(CHUNK)
    g_buf = np.empty((CHUNK, k))
    h_buf = np.empty((CHUNK, k, k))
    lo = part_ptr[p]
    hi = part_ptr[p + 1]
    for q0 in range(lo, hi, CHUNK):
        q1 = min(hi, q0 + CHUNK)
        _element_chunk(
            q0,
            q1,
            part_elements,
            q0,
            x,
            elements,
            dm_inv,
            volumes,
            model,
            param_a,
            param_b,
            # not literal Trues: the same compiled _element_chunk as element_terms' (numba types np.bool_ as bool)
            np.bool_(True),
            np.bool_(True),
            project,
            power,
            e_buf,
            g_buf,
            h_buf,
        )
        for q in range(q0, q1):
            t = part_elements[q]
            o = q - q0
            for a in range(nv):
                va = elements[t, a]
                if owner[va] != p:
                    continue
                for r in range(d):
                    grad[d * va + r] += g_buf[o, d * a + r]
                for b in range(nv):
                    p0 = base[t, a, b]
                    if p0 < 0:
                        continue
                    st = stride[t, a, b]
                    for i in range(d):
                        for j in range(d):
                            data[p0 + i * st + j] += weight * h_buf[o, d * a + i, d * b + j]


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _element_pass(
    u0,
    u1,
    x,
    elements,
    dm_inv,
    volumes,
    model,
    param_a,
    param_b,
    want_grad,
    want_hess,
    project,
    power,
    energy_out,
    grad_out,
    hess_out,
    owner,
    part_ptr,
    part_elements,
    base,
    stride,
    weight,
    data,
    grad,
):  # pragma: no cover
    """Units ``[u0, u1)`` of :func:`element_terms` (``part_ptr`` empty; a unit is a chunk of CHUNK elements) or of
    :func:`element_terms_scatter` (a unit is a part of the vertex rows), in one compiled entry point run on threads
    by :func:`idp.threaded.run_in_parts`: numba links every callee into each entry point's library and optimises
    and generates its code again there, so two entry points over the same element chunk cost two compilations of
    it (the two took 16.9 + 8.6 s of the first run's compile work on the Intel VM), and a ``prange`` loop once more."""
    scatter = part_ptr.size > 0
    m = elements.shape[0]
    no_ids = np.empty(0, np.int64)
    for u in range(u0, u1):
        if scatter:
            _scatter_part(
                np.int64(u),
                x,
                elements,
                dm_inv,
                volumes,
                model,
                param_a,
                param_b,
                project,
                power,
                owner,
                part_ptr,
                part_elements,
                base,
                stride,
                weight,
                data,
                grad,
            )
        else:
            q0 = np.int64(u) * CHUNK
            _element_chunk(
                q0,
                min(m, q0 + CHUNK),
                no_ids,
                np.int64(0),
                x,
                elements,
                dm_inv,
                volumes,
                model,
                param_a,
                param_b,
                want_grad,
                want_hess,
                project,
                power,
                energy_out,
                grad_out,
                hess_out,
            )


_NO_IDS = np.empty(0, np.int64)
_NO_PARTS = np.empty(0, np.int64)
_NO_SCATTER = np.empty((0, 0, 0), np.int32)
_NO_VALUES = np.empty(0)


def element_terms(
    x: np.ndarray,
    elements: np.ndarray,
    dm_inv: np.ndarray,
    volumes: np.ndarray,
    model: int,
    param_a: np.ndarray,
    param_b: np.ndarray,
    want_grad: bool,
    want_hess: bool,
    project: bool,
    power: float,
    energy_out: np.ndarray,
    grad_out: np.ndarray,
    hess_out: np.ndarray,
) -> None:
    """Fill per-element energy (m,), gradient (m,k) and Hessian (m,k,k) (the last two if asked).

    For the barrier models (NH, SD) elements with det F <= 0 get energy +inf and NaN gradient /
    Hessian (undefined there; callers keep iterates feasible with the inversion filter); ARAP and
    StVK are finite everywhere.  NH, StVK: param_a = mu, param_b = lambda; SD: param_a = weight;
    ARAP: param_a = mu (param_b unused).  ``power`` p ≠ 1 evaluates the p-norm extension of NH or SD
    (paper eq. 9, :mod:`idp.energies._pnorm_kernels`); 1 is the plain energy.  Parallel over chunks of
    CHUNK elements; every element writes only its own output rows (no races).
    """
    run_in_parts(
        _element_pass,
        (elements.shape[0] + CHUNK - 1) // CHUNK,
        x,
        elements,
        dm_inv,
        volumes,
        model,
        param_a,
        param_b,
        bool(want_grad),
        bool(want_hess),
        bool(project),
        float(power),
        energy_out,
        grad_out,
        hess_out,
        _NO_IDS,
        _NO_PARTS,
        _NO_IDS,
        _NO_SCATTER,
        _NO_SCATTER,
        0.0,
        _NO_VALUES,
        _NO_VALUES,
        grain=4,  # ≈ 0.3 ms of work a part (≈ 76 µs a chunk of neo-Hookean tetrahedra; see idp.threaded)
    )


def element_terms_scatter(
    x: np.ndarray,
    elements: np.ndarray,
    dm_inv: np.ndarray,
    volumes: np.ndarray,
    model: int,
    param_a: np.ndarray,
    param_b: np.ndarray,
    project: bool,
    power: float,
    owner: np.ndarray,
    part_ptr: np.ndarray,
    part_elements: np.ndarray,
    base: np.ndarray,
    stride: np.ndarray,
    weight: float,
    data: np.ndarray,
    grad: np.ndarray,
) -> None:
    """Gradient and Hessian of every element added straight into the gradient (flat, unweighted) and into the
    values of a block CSR matrix (× ``weight``), without the (m, k, k) array of element Hessians.

    Part p of the vertices (``owner[v] == p``) is handled by one thread: it evaluates the elements
    ``part_elements[part_ptr[p]:part_ptr[p+1]]`` (those with a vertex in part p, ascending) and adds only the rows
    of its own vertices, so no two threads write one entry (elements spanning two parts are evaluated by both).
    Every entry thus receives its elements' contributions in increasing element order, whatever the number of
    parts: the same sums, bit for bit, as evaluating all elements and then scattering them in order.
    ``base[t, a, b]`` is the CSR position of entry (0, 0) of the block of element t's vertices a, b (< 0: pinned),
    ``stride[t, a, b]`` its row stride (:class:`~idp.solver.assembly.FixedPatternAssembler`)."""
    if part_ptr.size < 2:  # no part: nothing to add (an empty part_ptr would select element_terms' loop)
        return
    k = elements.shape[1] * x.shape[1]
    run_in_parts(
        _element_pass,
        part_ptr.size - 1,
        x,
        elements,
        dm_inv,
        volumes,
        model,
        param_a,
        param_b,
        True,
        True,
        bool(project),
        float(power),
        _NO_VALUES,
        np.empty((0, k)),
        np.empty((0, k, k)),
        owner,
        part_ptr,
        part_elements,
        base,
        stride,
        float(weight),
        data,
        grad,
    )


@njit(cache=True, parallel=True, fastmath=False, error_model="numpy")
def element_jacobians(x: np.ndarray, elements: np.ndarray, dm_inv: np.ndarray) -> np.ndarray:
    """det F per element (m,) as det(Ds) det(Dm^{-1})."""
    m = elements.shape[0]
    d = x.shape[1]
    out = np.empty(m)
    nchunk = (m + CHUNK - 1) // CHUNK
    for ch in prange(nchunk):
        Ds = np.empty((d, d))
        Di = np.empty((d, d))
        for t in range(ch * CHUNK, min(m, (ch + 1) * CHUNK)):
            i0 = elements[t, 0]
            for a in range(d):
                ia = elements[t, a + 1]
                for r in range(d):
                    Ds[r, a] = x[ia, r] - x[i0, r]
                    Di[r, a] = dm_inv[t, r, a]
            out[t] = _det(Ds, d) * _det(Di, d)
    return out


# --------------------------------------------------------------------------------------
# numpy reference (tests only)
# --------------------------------------------------------------------------------------


def deformation_map(dm_inv: np.ndarray) -> np.ndarray:
    """B (m, d*d, k) with vec(F) = B x_local, vec row-major (F[r,c] -> r*d+c), x_local vertex-major."""
    m, d, _ = dm_inv.shape
    k = (d + 1) * d
    B = np.zeros((m, d * d, k))
    for r in range(d):
        for c in range(d):
            row = r * d + c
            for a in range(d):
                B[:, row, (a + 1) * d + r] = dm_inv[:, a, c]
            B[:, row, r] = -dm_inv[:, :, c].sum(axis=1)
    return B


def element_terms_reference(
    x: np.ndarray,
    elements: np.ndarray,
    dm_inv: np.ndarray,
    volumes: np.ndarray,
    model: int,
    param_a: np.ndarray,
    param_b: np.ndarray,
    project: bool = True,
    power: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plain numpy (energy (m,), gradient (m,k), Hessian (m,k,k)); the barrier models assume all det F > 0.

    Energy and stress are computed from F directly (ARAP's rotation from LAPACK's SVD); only the
    eigenvalue formulas are shared with the kernel, the modes are assembled through dF/dx."""
    m, d, _ = dm_inv.shape
    xe = x[elements]  # (m, d+1, d)
    Ds = np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1))
    F = Ds @ dm_inv
    a = param_a
    b = param_b
    U, sig, Vt = np.linalg.svd(F)
    V = np.transpose(Vt, (0, 2, 1))
    for M in (U, V):
        neg = np.linalg.det(M) < 0
        M[neg, :, -1] *= -1.0
        sig[neg, -1] *= -1.0
    lnJ = np.zeros(m)
    if model in (NEO_HOOKEAN, SYMMETRIC_DIRICHLET):
        J = np.linalg.det(F)
        lnJ = np.log(J)
        Fi = np.linalg.inv(F)
        FiT = np.transpose(Fi, (0, 2, 1))
        nF = np.einsum("mij,mij->m", F, F)
    if model == NEO_HOOKEAN:
        psi = 0.5 * a * (nF - d) - a * lnJ + 0.5 * b * lnJ**2
        P = a[:, None, None] * (F - FiT) + (b * lnJ)[:, None, None] * FiT
    elif model == SYMMETRIC_DIRICHLET:
        nFi = np.einsum("mij,mij->m", Fi, Fi)
        psi = a * (nF + nFi - 2 * d)
        P = 2 * a[:, None, None] * (F - FiT @ Fi @ FiT)
    elif model == ARAP:
        R = U @ Vt
        psi = a * np.einsum("mij,mij->m", F - R, F - R)
        P = 2 * a[:, None, None] * (F - R)
    else:
        Eg = 0.5 * (np.transpose(F, (0, 2, 1)) @ F - np.eye(d))
        trE = np.trace(Eg, axis1=1, axis2=2)
        psi = a * np.einsum("mij,mij->m", Eg, Eg) + 0.5 * b * trE**2
        P = F @ (2 * a[:, None, None] * Eg + (b * trE)[:, None, None] * np.eye(d))
    c1 = np.ones(m)
    c2 = np.zeros(m)
    if power != 1.0:  # p-norm (eq. 9) straight from ρ^p, without the overflow tail of the kernel
        psi0 = 2.0 * d * a if model == SYMMETRIC_DIRICHLET else 0.5 * d * a
        rho = (psi + psi0) / psi0
        psi = psi0 * rho**power / power
        c1 = rho ** (power - 1.0)
        c2 = (power - 1.0) * rho ** (power - 2.0) / psi0
        P = c1[:, None, None] * P
    B = deformation_map(dm_inv)
    grad = volumes[:, None] * np.einsum("mrk,mr->mk", B, P.reshape(m, d * d))

    si = sig[:, :, None]
    sj = sig[:, None, :]
    eye = np.eye(d, dtype=bool)[None]
    if model == ARAP:
        w2 = 2 * a[:, None, None]
        S = np.where(eye, w2, 0.0)
        flip = w2 + 0 * si * sj
        twist = w2 * (1 - 2 / np.maximum(si + sj, ARAP_TWIST_FLOOR))
    elif model == STVK:
        mu = a[:, None, None]
        la = b[:, None, None]
        h = 0.5 * la * ((sig**2).sum(axis=1)[:, None, None] - d)
        S = np.where(eye, mu * (3 * si * sj - 1) + h + la * si * sj, la * si * sj)
        flip = mu * (si**2 + si * sj + sj**2 - 1) + h
        twist = mu * (si**2 - si * sj + sj**2 - 1) + h
    elif model == NEO_HOOKEAN:
        cc = (a - b * lnJ)[:, None, None]
        S = np.where(eye, a[:, None, None] + (cc + b[:, None, None]) / (si * sj), b[:, None, None] / (si * sj))
        flip = a[:, None, None] + cc / (si * sj)
        twist = a[:, None, None] - cc / (si * sj)
    else:
        w2 = 2 * a[:, None, None]
        S = np.where(eye, w2 * (1 + 3 / (si * sj) ** 2), 0.0)
        p3 = (si * sj) ** 3
        flip = w2 * (1 + (si**2 + si * sj + sj**2) / p3)
        twist = w2 * (1 - (si**2 - si * sj + sj**2) / p3)
    if power != 1.0:
        if model == SYMMETRIC_DIRICHLET:
            dpsi = 2.0 * a[:, None] * (sig - sig**-3)
        else:
            dpsi = a[:, None] * sig - (a - b * lnJ)[:, None] / sig
        S = c1[:, None, None] * S + c2[:, None, None] * dpsi[:, :, None] * dpsi[:, None, :]
        flip = c1[:, None, None] * flip
        twist = c1[:, None, None] * twist
    lamS, Qs = np.linalg.eigh(S)
    modes = []
    lams = []
    for l in range(d):
        M = np.einsum("mi,ij->mij", Qs[:, :, l], np.eye(d))  # diag(q_l)
        modes.append(M)
        lams.append(lamS[:, l])
    for i in range(d):
        for j in range(i + 1, d):
            for sgn, ev in ((1.0, flip), (-1.0, twist)):
                M = np.zeros((m, d, d))
                M[:, i, j] = np.sqrt(0.5)
                M[:, j, i] = sgn * np.sqrt(0.5)
                modes.append(M)
                lams.append(ev[:, i, j])
    K = np.zeros((m, d * d, d * d))
    for M, lam in zip(modes, lams, strict=True):
        G = (U @ M @ Vt).reshape(m, d * d)
        if project:
            lam = np.maximum(lam, 0.0)
        K += lam[:, None, None] * G[:, :, None] * G[:, None, :]
    hess = volumes[:, None, None] * np.einsum("mak,mab,mbl->mkl", B, K, B)
    return volumes * psi, grad, hess
