"""Projection of small dense symmetric matrices onto the positive semidefinite cone (numba).

``project_psd(H, k, work)`` replaces the leading k x k block of H by V max(Λ, 0) Vᵀ, where
H[:k, :k] = V Λ Vᵀ.  It is meant for the per-contact Hessian blocks of the IPC barrier
(k = 3, 6, 9, 12), called from a numba ``prange`` loop with one ``work`` array per thread or
chunk (shape at least (WORK_ROWS, 12), float64); nothing is allocated inside.

Method (written from the textbook mathematics):

1. Symmetrise in place (H <- (H + Hᵀ)/2; a no-op for symmetric input) and work on a copy
   scaled by s = max |H_ij|, so every entry is at most 1 (no over/underflow for entries from
   ~1e-300 to ~1e300; all tolerances below are relative to s).
2. Fast path (skipped when a diagonal entry is < -TOL_PSD * s): LDLᵀ with lazy diagonal
   pivoting (the natural pivot while it exceeds TOL_PSD, else the largest remaining diagonal
   entry).  If all pivots used are positive and the Schur complement that is left when no
   diagonal entry exceeds TOL_PSD has every entry below TOL_PSD (exactly semidefinite
   matrices such as c n nᵀ end this way), the matrix is PSD up to ~k * TOL_PSD * s and is
   returned unchanged.  A negative diagonal entry in a Schur complement ends the attempt.
3. k = 3: one Givens rotation to tridiagonal form, implicit QR with Wilkinson shifts, the
   rotation product accumulated, all in registers (`_project3`).
4. k > 3: Householder tridiagonalisation A = P T Pᵀ, then implicit symmetric QR on T with
   Wilkinson shifts (2 x 2 blocks diagonalised directly) computing eigenvalues only but
   recording every Givens rotation.  With m- eigenvalues below -TOL_EIG * s and m+ above
   TOL_EIG * s, only min(m-, m+) <= k/2 eigenvectors are formed, by replaying the recorded
   rotations backwards on unit vectors (orthonormal to rounding error, also for repeated
   eigenvalues: no inverse iteration) and applying the reflectors:
       m- <= m+ :  H <- H - Σ_{λ<0} λ u uᵀ
       otherwise:  H <- Σ_{λ>0} λ u uᵀ
   Eigenvalues within TOL_EIG * s of zero are dropped (error at most k * TOL_EIG * s).
5. If the QR iteration hits MAX_QR_ITERS (not seen in practice; about 2k iterations are
   used) the projection is recomputed by cyclic Jacobi with a sweep cap, so every call
   terminates.

Measured per call from an njit loop, one thread (AMD EPYC VM, ~3.7 GHz; numpy's eigh called
inside numba, plus the clamped reassembly, in brackets): general path on a g gᵀ + b S,
S random symmetric: k = 3: 0.23 µs (1.2), 6: 1.06 µs (3.5), 9: 2.3 µs (7.0), 12: 4.0 µs
(12.1); fast path on PD / rank-1 input: k = 3: 0.05, 6: 0.11 / 0.09, 9: 0.21 / 0.15,
12: 0.34 / 0.22 µs.  Against eigh the result agrees to ~1e-14 ||H||_F.

The output block is exactly symmetric and finite for finite input; entries of H outside
the leading k x k block are not touched.  Non-finite input is left as is (after
symmetrising).  No global state: calls with distinct ``work`` arrays are thread-safe.
"""

from __future__ import annotations

import math

import numpy as np

from idp._leaf import leaf_njit
from idp._small_dense import symmetric_eigen_jacobi

#: Largest supported block size (columns of ``work``).
KMAX = 12

#: Total implicit QR iterations allowed before falling back to Jacobi (about 2 k are used).
MAX_QR_ITERS = 8 * KMAX

# work row layout: rows 0..11 hold the scaled copy of the block (row j later holds
# Householder vector j, then the eigenvectors formed)
_D = 12  # diagonal of T, then eigenvalues (scaled)
_E = 13  # off-diagonal of T
_BETA = 14  # Householder coefficients
_TMP = 15  # p / w vectors of the tridiagonal reduction; eigenvector indices; dot products
_VEC = 16  # rows 16..27: eigenvectors being formed, one per column (at most k // 2 of them)
_NV = KMAX // 2  # eigenvector columns; loops over them have this constant trip count (unrolled)
_ROT = _VEC + KMAX  # two rows per QR iteration: cosines, sines; column 11 holds lo / hi

#: Rows the caller must provide in ``work`` (shape (WORK_ROWS, 12), float64).
WORK_ROWS = _ROT + 2 * MAX_QR_ITERS

#: Relative (to max |H_ij|) size below which a remaining Schur complement counts as zero.
TOL_PSD = 1e-14
#: Relative (to max |H_ij|) size below which an eigenvalue counts as zero.
TOL_EIG = 1e-15

_EPS = 2.220446049250313e-16

#: Return values of ``project_psd``: which path handled the block.
PATH_TRIVIAL = 0  # zero or non-finite block: left as is
PATH_FAST = 1  # certified PSD by the LDLᵀ test: H not written (returned bit for bit)
PATH_GENERAL = 2  # eigenvalue path (3 x 3 register path, or tridiagonal QR)
PATH_JACOBI = 3  # Jacobi fallback after the QR iteration cap


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _ldlt_is_psd(A: np.ndarray, k: int, tol: float) -> bool:
    """PSD test by LDLᵀ on the upper triangle of A[:k, :k] (destroyed; lower ignored).

    Lazy diagonal pivoting: the natural pivot A[j, j] is used while it exceeds tol (no search
    for definite matrices); otherwise the largest remaining diagonal entry is swapped in.
    True when every pivot used is > tol and the Schur complement left when no diagonal
    entry exceeds tol has all entries <= tol: then A + E = L D Lᵀ + R with D > 0,
    |E_ij| <~ k u max|A| (positive pivots bound |L| D |Lᵀ| by Cauchy-Schwarz) and ||R|| <= k tol.
    False as soon as a diagonal entry < -tol appears (indefinite, up to rounding: a wrong
    call only sends the matrix to the general path)."""
    for i in range(k):
        if A[i, i] < -tol:
            return False
    for j in range(k):
        dmax = A[j, j]
        if not (dmax > tol):
            p = j
            for i in range(j + 1, k):
                if A[i, i] > dmax:
                    dmax = A[i, i]
                    p = i
            if not (dmax > tol):
                for a in range(j, k):
                    if not (A[a, a] >= -tol):  # (written so that NaN rejects)
                        return False
                    for b in range(a + 1, k):
                        if not (abs(A[a, b]) <= tol):
                            return False
                return True
            # symmetric swap of indices j < p in upper-triangle storage (indices >= j only)
            t = A[j, j]
            A[j, j] = A[p, p]
            A[p, p] = t
            for i in range(j + 1, p):
                t = A[j, i]
                A[j, i] = A[i, p]
                A[i, p] = t
            for i in range(p + 1, k):
                t = A[j, i]
                A[j, i] = A[p, i]
                A[p, i] = t
        inv = 1.0 / dmax
        uj = np.uintp(j)
        for a in range(j + 1, k):
            ua = np.uintp(a)
            la = A[uj, ua] * inv
            for b in range(a, k):
                ub = np.uintp(b)  # unsigned indices: no wrap-around test in the inner loop
                A[ua, ub] -= la * A[uj, ub]
            if A[ua, ua] < -tol:
                return False
    return True


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _tridiagonalize(work: np.ndarray, k: int) -> None:
    """Householder reduction of the symmetric block work[:k, :k] to T (diag in _D, off in _E).

    Reflector j is I - beta_j v vᵀ on indices j+1..k-1, with v kept in row j (columns > j)."""
    for j in range(k - 2):
        n0 = j + 1
        x0 = work[j, n0]
        sig2 = 0.0
        for i in range(n0 + 1, k):
            xi = work[j, i]
            sig2 += xi * xi
        work[_D, j] = work[j, j]
        if sig2 < 1e-200:
            # nothing to eliminate (entries below 1e-100 of the largest are dropped: this keeps
            # beta = 1 / (sig |v0|) finite)
            work[_E, j] = x0
            work[_BETA, j] = 0.0
            continue
        sig = math.sqrt(x0 * x0 + sig2)
        v0 = x0 + math.copysign(sig, x0)
        work[_E, j] = -math.copysign(sig, x0)
        b = 1.0 / (sig * abs(v0))
        work[_BETA, j] = b
        work[j, n0] = v0
        # p = beta A v (A = trailing block), K = beta/2 pᵀv, w = p - K v
        uj = np.uintp(j)
        for i in range(n0, k):
            ui = np.uintp(i)
            acc = 0.0
            for l in range(n0, k):
                ul = np.uintp(l)  # unsigned indices: no wrap-around test in the inner loops
                acc += work[ui, ul] * work[uj, ul]
            work[_TMP, ui] = b * acc
        pv = 0.0
        for i in range(n0, k):
            pv += work[_TMP, i] * work[j, i]
        kk = 0.5 * b * pv
        for i in range(n0, k):
            ui = np.uintp(i)
            work[_TMP, ui] -= kk * work[uj, ui]
        # A <- A - v wᵀ - w vᵀ (full trailing block, rows contiguous)
        for i in range(n0, k):
            ui = np.uintp(i)
            vi = work[uj, ui]
            wi = work[_TMP, ui]
            for l in range(n0, k):
                ul = np.uintp(l)
                work[ui, ul] -= vi * work[_TMP, ul] + wi * work[uj, ul]
    if k >= 2:
        work[_D, k - 2] = work[k - 2, k - 2]
        work[_E, k - 2] = work[k - 2, k - 1]
    work[_D, k - 1] = work[k - 1, k - 1]


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _tridiagonal_qr(work: np.ndarray, k: int) -> int:
    """Eigenvalues of T (in place in work[_D]) by implicit QR with Wilkinson shifts.

    Rotation i of iteration t (plane (i, i+1), J = [[c, s], [-s, c]], T <- J T Jᵀ) is stored
    as work[_ROT + 2t, i] = c, work[_ROT + 2t + 1, i] = s; lo and hi in column 11.
    Returns the iteration count, or -1 when MAX_QR_ITERS was reached."""
    nit = 0
    hi = k - 1
    while hi > 0:
        lo = hi
        split = False  # a condition, not ``break`` (numba's reference-count pruning, see _distance_kernels)
        while lo > 0 and not split:
            ee = abs(work[_E, lo - 1])
            if ee <= _EPS * (abs(work[_D, lo - 1]) + abs(work[_D, lo])) or ee <= 1e-16:
                work[_E, lo - 1] = 0.0
                split = True
            else:
                lo -= 1
        if lo == hi:
            hi -= 1
            continue
        if nit >= MAX_QR_ITERS:
            return -1
        rc = _ROT + 2 * nit
        rs = rc + 1
        work[rc, KMAX - 1] = lo
        work[rs, KMAX - 1] = hi
        nit += 1
        b = work[_E, hi - 1]
        if hi - lo == 1:
            # 2 x 2 block: diagonalise it directly with one rotation, tan θ = t where
            # t² - 2τt - 1 = 0, τ = (d_hi - d_lo) / (2b) (root of smaller magnitude)
            a = work[_D, lo]
            dd = work[_D, hi]
            tau = (dd - a) / (2.0 * b)
            t = -math.copysign(1.0, tau) / (abs(tau) + math.sqrt(1.0 + tau * tau))
            c = 1.0 / math.sqrt(1.0 + t * t)
            s = t * c
            work[rc, lo] = c
            work[rs, lo] = s
            cc = c * c
            ss = s * s
            t2 = 2.0 * c * s * b
            work[_D, lo] = cc * a + t2 + ss * dd
            work[_D, hi] = ss * a - t2 + cc * dd
            work[_E, lo] = 0.0
            hi -= 1
            continue
        # Wilkinson shift from the trailing 2 x 2 of the block
        delta = 0.5 * (work[_D, hi - 1] - work[_D, hi])
        den = delta + math.copysign(math.sqrt(delta * delta + b * b), delta)
        mu = work[_D, hi] - b * (b / den)
        # Bulge chase.  The 2 x 2 update only needs c², s², cs, obtained from r² with one
        # division; the square root (for c, s themselves) stays off the critical path.
        a = work[_D, lo]
        bb = work[_E, lo]  # current e[i]
        x = a - mu
        z = bb
        z2 = bb * bb
        for i in range(lo, hi):
            x2 = x * x
            r2 = x2 + z2
            if r2 > 1e-280:
                inv2 = 1.0 / r2
                ri = math.sqrt(inv2)  # one division for both 1/r² and 1/r
                c = x * ri
                s = z * ri
                r = r2 * ri
                cc = x2 * inv2
                ss = z2 * inv2
                cs = (x * z) * inv2
            else:
                m = max(abs(x), abs(z))
                if m == 0.0:
                    c = 1.0
                    s = 0.0
                    r = 0.0
                else:
                    xs = x / m
                    zs = z / m
                    rr = math.sqrt(xs * xs + zs * zs)
                    c = xs / rr
                    s = zs / rr
                    r = rr * m
                cc = c * c
                ss = s * s
                cs = c * s
            work[rc, i] = c
            work[rs, i] = s
            if i > lo:
                work[_E, i - 1] = r
            dd = work[_D, i + 1]
            t2 = 2.0 * cs * bb
            work[_D, i] = cc * a + t2 + ss * dd
            bnew = cs * (dd - a) + (cc - ss) * bb
            a = ss * a - t2 + cc * dd
            if i < hi - 1:
                f = work[_E, i + 1]
                z = s * f
                z2 = ss * (f * f)
                bb = c * f
                x = bnew
            else:
                work[_E, i] = bnew
        work[_D, hi] = a
    return nit


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _eigenvectors(work: np.ndarray, k: int, nit: int, nv: int) -> None:
    """Rows 0..nv-1 of work <- eigenvectors (length k) for the eigenvalue indices work[_E, :nv].

    y = J_1ᵀ ... J_Nᵀ e_j (recorded rotations replayed backwards), then u = H_0 ... H_{k-3} y,
    with the vectors as the columns of rows _VEC.._VEC+k-1 (contiguous over the vectors;
    1, 3 or _NV columns are processed); finally transposed into rows 0..nv-1 (the
    Householder vectors are no longer needed then)."""
    width = 1 if nv == 1 else (3 if nv <= 3 else _NV)
    lo_s = k
    hi_s = -1
    for i in range(k):
        ui = np.uintp(_VEC + i)
        for q in range(_NV):
            work[ui, q] = 0.0
    for q in range(nv):
        j = int(work[_E, q])
        work[_VEC + j, q] = 1.0
        lo_s = min(lo_s, j)
        hi_s = max(hi_s, j)
    for t in range(nit - 1, -1, -1):
        rc = _ROT + 2 * t
        lo = int(work[rc, KMAX - 1])
        hi = int(work[rc + 1, KMAX - 1])
        if lo > hi_s or hi < lo_s:
            continue  # the vectors are still zero on this block
        i0 = min(hi - 1, hi_s)
        for i in range(i0, lo - 1, -1):
            c = work[rc, i]
            s = work[rc + 1, i]
            r0 = np.uintp(_VEC + i)
            r1 = np.uintp(_VEC + i + 1)
            # constant trip counts (1, 3 or _NV columns) so that the loops unroll
            if width == 1:
                y0 = work[r0, 0]
                y1 = work[r1, 0]
                work[r0, 0] = c * y0 - s * y1
                work[r1, 0] = s * y0 + c * y1
            elif width == 3:
                for q in range(3):
                    y0 = work[r0, q]
                    y1 = work[r1, q]
                    work[r0, q] = c * y0 - s * y1
                    work[r1, q] = s * y0 + c * y1
            else:
                for q in range(_NV):
                    y0 = work[r0, q]
                    y1 = work[r1, q]
                    work[r0, q] = c * y0 - s * y1
                    work[r1, q] = s * y0 + c * y1
        lo_s = min(lo_s, lo)
        hi_s = max(hi_s, i0 + 1)
    # u = H_0 ... H_{k-3} y, H_j = I - beta_j v vᵀ (v in row j, columns > j)
    for j in range(k - 3, -1, -1):
        b = work[_BETA, j]
        if b == 0.0:
            continue
        uj = np.uintp(j)
        if width == 1:
            acc = 0.0
            for i in range(j + 1, k):
                acc += work[uj, np.uintp(i)] * work[np.uintp(_VEC + i), 0]
            acc *= b
            for i in range(j + 1, k):
                work[np.uintp(_VEC + i), 0] -= acc * work[uj, np.uintp(i)]
            continue
        for q in range(_NV):
            work[_TMP, q] = 0.0
        for i in range(j + 1, k):
            vi = b * work[uj, np.uintp(i)]
            ri = np.uintp(_VEC + i)
            if width == 3:
                for q in range(3):
                    work[_TMP, q] += vi * work[ri, q]
            else:
                for q in range(_NV):
                    work[_TMP, q] += vi * work[ri, q]
        for i in range(j + 1, k):
            vi = work[uj, np.uintp(i)]
            ri = np.uintp(_VEC + i)
            if width == 3:
                for q in range(3):
                    work[ri, q] -= vi * work[_TMP, q]
            else:
                for q in range(_NV):
                    work[ri, q] -= vi * work[_TMP, q]
    for q in range(nv):
        for i in range(k):
            work[q, i] = work[_VEC + i, q]


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _jacobi_project(H: np.ndarray, k: int, work: np.ndarray, scale: float) -> None:
    """Fallback: cyclic Jacobi on the scaled block (sweep cap), H <- Σ max(λ,0) u uᵀ."""
    inv = 1.0 / scale
    for i in range(k):
        for j in range(k):
            work[i, j] = H[i, j] * inv
    lam = work[_D, :k]
    Q = work[_VEC : _VEC + k, :k]  # eigenvectors in columns
    symmetric_eigen_jacobi(work[:k, :k], k, Q, lam)
    for i in range(k):
        for j in range(i, k):
            acc = 0.0
            for q in range(k):
                if lam[q] > 0.0:
                    acc += lam[q] * Q[i, q] * Q[j, q]
            acc *= scale
            H[i, j] = acc
            H[j, i] = acc


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _rot2(a: float, b: float, d: float) -> tuple[float, float]:
    """(c, s) with J [[a, b], [b, d]] Jᵀ diagonal, J = [[c, s], [-s, c]] (b != 0, |angle| <= 45°).

    tan θ = t solves t² - 2τt - 1 = 0, τ = (d - a) / (2b); the root of smaller magnitude."""
    tau = (d - a) / (2.0 * b)
    t = -math.copysign(1.0, tau) / (abs(tau) + math.sqrt(1.0 + tau * tau))
    c = 1.0 / math.sqrt(1.0 + t * t)
    return c, t * c


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _negligible(e: float, d0: float, d1: float) -> bool:
    """Off-diagonal e of a scaled tridiagonal is negligible next to its diagonal neighbours."""
    ae = abs(e)
    return ae <= _EPS * (abs(d0) + abs(d1)) or ae <= 1e-16


@leaf_njit(error_model="numpy", fastmath={"contract"})
def _project3(H: np.ndarray, work: np.ndarray, scale: float) -> bool:
    """3 x 3 general path in registers: one Givens rotation to tridiagonal form, implicit QR with
    Wilkinson shifts (a final 2 x 2 block is diagonalised directly), the rotation product W
    (eigenvectors = rows of W) accumulated on the fly.  False if the iteration cap was hit."""
    inv = 1.0 / scale
    a00 = H[0, 0] * inv
    a01 = H[0, 1] * inv
    a02 = H[0, 2] * inv
    a11 = H[1, 1] * inv
    a12 = H[1, 2] * inv
    a22 = H[2, 2] * inv
    w00, w01, w02 = 1.0, 0.0, 0.0
    w10, w11, w12 = 0.0, 1.0, 0.0
    w20, w21, w22 = 0.0, 0.0, 1.0
    d0 = a00
    r2 = a01 * a01 + a02 * a02
    if a02 != 0.0 and r2 > 1e-280:
        ri = 1.0 / math.sqrt(r2)
        c = a01 * ri
        s = a02 * ri
        e0 = r2 * ri
        cc = c * c
        ss = s * s
        t2 = 2.0 * c * s * a12
        d1 = cc * a11 + t2 + ss * a22
        d2 = ss * a11 - t2 + cc * a22
        e1 = c * s * (a22 - a11) + (cc - ss) * a12
        w11, w12 = c, s
        w21, w22 = -s, c
    else:  # a02 is zero or below 1e-140 * max|H_ij|: drop it
        e0 = a01
        d1 = a11
        d2 = a22
        e1 = a12
    converged = False
    for _it in range(MAX_QR_ITERS):
        if _negligible(e1, d1, d2):
            if not _negligible(e0, d0, d1):
                c, s = _rot2(d0, e0, d1)
                cc = c * c
                ss = s * s
                t2 = 2.0 * c * s * e0
                d0, d1 = cc * d0 + t2 + ss * d1, ss * d0 - t2 + cc * d1
                w00, w10 = c * w00 + s * w10, c * w10 - s * w00
                w01, w11 = c * w01 + s * w11, c * w11 - s * w01
                w02, w12 = c * w02 + s * w12, c * w12 - s * w02
            converged = True
            break
        if _negligible(e0, d0, d1):
            c, s = _rot2(d1, e1, d2)
            cc = c * c
            ss = s * s
            t2 = 2.0 * c * s * e1
            d1, d2 = cc * d1 + t2 + ss * d2, ss * d1 - t2 + cc * d2
            w10, w20 = c * w10 + s * w20, c * w20 - s * w10
            w11, w21 = c * w11 + s * w21, c * w21 - s * w11
            w12, w22 = c * w12 + s * w22, c * w22 - s * w12
            converged = True
            break
        # Wilkinson shift from the trailing 2 x 2
        delta = 0.5 * (d1 - d2)
        den = delta + math.copysign(math.sqrt(delta * delta + e1 * e1), delta)
        mu = d2 - e1 * (e1 / den)
        # rotation in plane (0, 1): x = d0 - mu, z = e0 (> 1e-16, so r > 0)
        x = d0 - mu
        ri = 1.0 / math.sqrt(x * x + e0 * e0)
        c = x * ri
        s = e0 * ri
        cc = c * c
        ss = s * s
        t2 = 2.0 * c * s * e0
        a = d0
        d0 = cc * a + t2 + ss * d1
        e0 = c * s * (d1 - a) + (cc - ss) * e0
        d1 = ss * a - t2 + cc * d1
        z = s * e1
        e1 = c * e1
        w00, w10 = c * w00 + s * w10, c * w10 - s * w00
        w01, w11 = c * w01 + s * w11, c * w11 - s * w01
        w02, w12 = c * w02 + s * w12, c * w12 - s * w02
        # rotation in plane (1, 2) chasing the bulge z at (0, 2)
        r2 = e0 * e0 + z * z
        if r2 > 1e-280:
            ri = 1.0 / math.sqrt(r2)
            c = e0 * ri
            s = z * ri
            e0 = r2 * ri
            cc = c * c
            ss = s * s
            t2 = 2.0 * c * s * e1
            a = d1
            d1 = cc * a + t2 + ss * d2
            e1 = c * s * (d2 - a) + (cc - ss) * e1
            d2 = ss * a - t2 + cc * d2
            w10, w20 = c * w10 + s * w20, c * w20 - s * w10
            w11, w21 = c * w11 + s * w21, c * w21 - s * w11
            w12, w22 = c * w12 + s * w22, c * w22 - s * w12
    if not converged:
        return False
    nneg = 0
    npos = 0
    for lam in (d0, d1, d2):
        if lam < -TOL_EIG:
            nneg += 1
        elif lam > TOL_EIG:
            npos += 1
    if nneg == 0:
        return True
    if npos == 0:
        for i in range(3):
            for j in range(3):
                H[i, j] = 0.0
        return True
    if nneg <= npos:  # H <- H - Σ_{λ<0} λ u uᵀ
        base = 1.0
        c0 = -scale * d0 if d0 < -TOL_EIG else 0.0
        c1 = -scale * d1 if d1 < -TOL_EIG else 0.0
        c2 = -scale * d2 if d2 < -TOL_EIG else 0.0
    else:  # H <- Σ_{λ>0} λ u uᵀ
        base = 0.0
        c0 = scale * d0 if d0 > TOL_EIG else 0.0
        c1 = scale * d1 if d1 > TOL_EIG else 0.0
        c2 = scale * d2 if d2 > TOL_EIG else 0.0
    h00 = base * H[0, 0] + c0 * w00 * w00 + c1 * w10 * w10 + c2 * w20 * w20
    h01 = base * H[0, 1] + c0 * w00 * w01 + c1 * w10 * w11 + c2 * w20 * w21
    h02 = base * H[0, 2] + c0 * w00 * w02 + c1 * w10 * w12 + c2 * w20 * w22
    h11 = base * H[1, 1] + c0 * w01 * w01 + c1 * w11 * w11 + c2 * w21 * w21
    h12 = base * H[1, 2] + c0 * w01 * w02 + c1 * w11 * w12 + c2 * w21 * w22
    h22 = base * H[2, 2] + c0 * w02 * w02 + c1 * w12 * w12 + c2 * w22 * w22
    H[0, 0] = h00
    H[1, 1] = h11
    H[2, 2] = h22
    H[0, 1] = h01
    H[1, 0] = h01
    H[0, 2] = h02
    H[2, 0] = h02
    H[1, 2] = h12
    H[2, 1] = h12
    return True


@leaf_njit(error_model="numpy", fastmath={"contract"})
def project_psd(H: np.ndarray, k: int, work: np.ndarray) -> int:
    """In place: H[:k,:k] <- V max(Λ,0) Vᵀ where H[:k,:k] = V Λ Vᵀ (symmetric input; output exactly symmetric).

    work: float64 scratch of shape at least (WORK_ROWS, 12) (module constant WORK_ROWS) so
    the caller can allocate it once per thread/chunk; no allocation inside.  k <= 12
    (ValueError otherwise, or when H / work are too small).
    The symmetric part (H + Hᵀ)/2 is used (written back; a no-op for symmetric input).
    Matrices that are PSD up to ~k * TOL_PSD * max|H_ij| are returned unchanged.

    Returns the path taken (module constants): PATH_TRIVIAL (zero or non-finite block, left
    as is), PATH_FAST (certified PSD by the LDLᵀ test: H not written at all, so it is returned
    bit for bit), PATH_GENERAL (eigenvalue path, k = 1 included), PATH_JACOBI (fallback).
    Which of PATH_FAST / PATH_GENERAL a matrix that is semidefinite only up to rounding takes
    can depend on the CPU (FMA contraction, target ISA); the result agrees either way."""
    if k > KMAX or H.shape[0] < k or H.shape[1] < k or work.shape[0] < WORK_ROWS or work.shape[1] < KMAX:
        raise ValueError("project_psd: need k <= 12, H at least k x k, work (WORK_ROWS, 12)")
    # symmetrise, find the scale and the smallest diagonal entry
    s = 0.0
    total = 0.0  # NaN / inf detector
    dmin = np.inf
    for i in range(k):
        ui = np.uintp(i)
        dmin = min(dmin, H[ui, ui])
        for j in range(i, k):
            uj = np.uintp(j)
            a = H[ui, uj]
            if j != i:
                b = H[uj, ui]
                if a != b:
                    a = 0.5 * a + 0.5 * b
                    H[ui, uj] = a
                    H[uj, ui] = a
            aa = abs(a)
            s = max(s, aa)
            total += aa
    if s == 0.0 or not (total < np.inf):
        return PATH_TRIVIAL  # zero (already PSD) or non-finite input
    if k == 1:
        if H[0, 0] < 0.0:
            H[0, 0] = 0.0
        return PATH_GENERAL
    inv = 1.0 / s
    if dmin >= -TOL_PSD * s:
        # fast path: LDLᵀ with lazy pivoting on (the upper triangle of) a scaled copy
        for i in range(k):
            ui = np.uintp(i)
            for j in range(i, k):
                uj = np.uintp(j)
                work[ui, uj] = H[ui, uj] * inv
        if _ldlt_is_psd(work, k, TOL_PSD):
            return PATH_FAST
    if k == 3:
        if not _project3(H, work, s):
            _jacobi_project(H, k, work, s)
            return PATH_JACOBI
        return PATH_GENERAL
    # general path on the scaled block
    for i in range(k):
        ui = np.uintp(i)
        for j in range(k):
            uj = np.uintp(j)
            work[ui, uj] = H[ui, uj] * inv
    _tridiagonalize(work, k)
    nit = _tridiagonal_qr(work, k)
    if nit < 0:
        _jacobi_project(H, k, work, s)
        return PATH_JACOBI
    nneg = 0
    npos = 0
    for i in range(k):
        lam = work[_D, i]
        if lam < -TOL_EIG:
            nneg += 1
        elif lam > TOL_EIG:
            npos += 1
    if nneg == 0:
        return PATH_GENERAL
    if npos == 0:
        for i in range(k):
            for j in range(k):
                H[i, j] = 0.0
        return PATH_GENERAL
    keep_h = nneg <= npos
    # indices of the eigenvectors to form, kept (as floats) in the now unused off-diagonal row
    nv = 0
    for i in range(k):
        lam = work[_D, i]
        if (keep_h and lam < -TOL_EIG) or ((not keep_h) and lam > TOL_EIG):
            work[_E, nv] = i
            nv += 1
    _eigenvectors(work, k, nit, nv)
    if keep_h:
        sign = -1.0  # H <- H - Σ_{λ<0} λ u uᵀ
    else:
        sign = 1.0  # H <- Σ_{λ>0} λ u uᵀ
        for i in range(k):
            for j in range(i, k):
                H[i, j] = 0.0
    for q in range(nv):
        lam = sign * s * work[_D, int(work[_E, q])]
        uq = np.uintp(q)
        for i in range(k):
            ui = np.uintp(i)
            ci = lam * work[uq, ui]
            for j in range(i, k):
                uj = np.uintp(j)
                H[ui, uj] += ci * work[uq, uj]
    for i in range(k):
        for j in range(i + 1, k):
            H[j, i] = H[i, j]
    return PATH_GENERAL
