"""Numba kernels for the IPC contact terms: squared distances, their derivatives, the
closest-feature classification, the edge-edge mollifier and the log barrier.

Everything works on *squared* Euclidean distances (as ipctk does). Points are float64
arrays of shape (3,); a stencil ``X`` is a (k, 3) array whose rows are the stencil
vertices in the order listed below (the classifications take the whole (4, 3) pair, point and
triangle or edge and edge, and read it in place: no row views in the hot loops, each of which
costs numba two atomic reference-count updates). For the same reason the helpers that take arrays have no
``break`` in a loop: numba increfs array arguments on entry and decrefs them on exit, and its reference-count
pruning removes those pairs in functions without loop breaks (checked on the LLVM IR) but not in a loop with a
``break``; with 2 threads these atomic updates took half the time of the CCD bounds and of the candidate
classification on bunny_700. Gradients and Hessians are taken w.r.t. the flattened
stencil in vertex-major order ``[x0, y0, z0, x1, y1, z1, ...]`` (length 3k).

Distance kinds (stencil, k rows)
--------------------------------
=========  ===========================  ==========================================
``PP``     p, q                 (k=2)   ||p - q||^2
``PL``     p, e0, e1            (k=3)   p to the infinite line through e0, e1
``PPLANE`` p, t0, t1, t2        (k=4)   p to the plane through t0, t1, t2
``LL``     ea0, ea1, eb0, eb1   (k=4)   infinite line (ea0, ea1) to line (eb0, eb1)
=========  ===========================  ==========================================

Derivatives (one formula for all kinds)
---------------------------------------
Each distance is ``d = |w|^2`` with ``w = sum_V c_V(lam) x_V`` the vector between the two
closest points, where ``lam`` are the (at most two) closest-point parameters and the
coefficients ``c_V`` are affine in ``lam`` with ``dc_V/dlam = delta_V``:

* PP:     w = p - q                                  (no parameter)
* PL:     w = p - (1-t) e0 - t e1,                   lam = t
* PPLANE: w = p - (1-u-v) t0 - u t1 - v t2,          lam = (u, v)
* LL:     w = (1-s) ea0 + s ea1 - (1-t) eb0 - t eb1, lam = (s, t)

With ``J = dw/dlam`` (3 x m) and ``G = J^T J`` the optimality condition is ``J^T w = 0``.
By the envelope theorem ``dd/dx_V = 2 c_V w`` and differentiating ``J^T w = 0`` gives

    d^2 d / dx_V dx_W = 2 c_V c_W I - 2 Z_V G^{-1} Z_W^T,   Z_V = c_V J + w delta_V^T  (3 x m).

``det G`` is ``|u|^2`` (PL) or ``|n|^2`` with n the plane normal / the cross product of the
two line directions (PPLANE, LL), computed as ``n.n`` for accuracy. For PPLANE and LL the
value is ``(r.n)^2 / n.n`` and ``w`` is taken along ``n`` exactly. The Hessians are the
true (indefinite) Hessians; nothing is projected here. Degenerate inputs (zero-length
edge, collinear triangle, exactly parallel lines for LL) divide by zero and return
inf/nan (``error_model="numpy"``): the classification below never selects them.

Closest-feature classification (integers equal to ipctk 1.6.1's enums)
----------------------------------------------------------------------
Point-triangle (``point_triangle_type``), local vertices 0 = p, 1 = t0, 2 = t1, 3 = t2:

====  ======  =======  =======================
type  name    kind     ``PT_LOCAL`` row
====  ======  =======  =======================
0     P_T0    PP       p, t0
1     P_T1    PP       p, t1
2     P_T2    PP       p, t2
3     P_E0    PL       p, t0, t1   (edge t0-t1)
4     P_E1    PL       p, t1, t2   (edge t1-t2)
5     P_E2    PL       p, t2, t0   (edge t2-t0)
6     P_T     PPLANE   p, t0, t1, t2
====  ======  =======  =======================

Edge-edge (``edge_edge_type``), local vertices 0 = ea0, 1 = ea1, 2 = eb0, 3 = eb1:

====  ========  ======  =====================================
type  name      kind    ``EE_LOCAL`` row
====  ========  ======  =====================================
0     EA0_EB0   PP      ea0, eb0
1     EA0_EB1   PP      ea0, eb1
2     EA1_EB0   PP      ea1, eb0
3     EA1_EB1   PP      ea1, eb1
4     EA_EB0    PL      eb0, ea0, ea1   (point eb0 to edge A)
5     EA_EB1    PL      eb1, ea0, ea1   (point eb1 to edge A)
6     EA0_EB    PL      ea0, eb0, eb1   (point ea0 to edge B)
7     EA1_EB    PL      ea1, eb0, eb1   (point ea1 to edge B)
8     EA_EB     LL      ea0, ea1, eb0, eb1
====  ========  ======  =====================================

``PT_KIND[type]`` / ``EE_KIND[type]`` give the distance kind and ``PT_LOCAL[type, :]`` /
``EE_LOCAL[type, :]`` the local vertex ids of the stencil in order, padded with -1;
``STENCIL_SIZE[kind]`` is the number of stencil rows. ``gather_stencil`` copies them.

Edge-edge follows ipctk: nearly parallel edges, ``|u x v|^2 < 2.5e-16 |u|^2 |v|^2`` (the
switch point of ``ipctk.edge_edge_distance_type``, measured), use a separate rule that
only returns point-edge / point-point types (the line-line distance is ill-posed there;
reconstructed from ipctk's behaviour, it agrees on all tested parallel configurations);
otherwise the closest pair of the two segments is found by clamping the closest-point
parameters of the lines. Zero-length edges are special-cased like ipctk. One deliberate
difference: the line parameters use ``n = u x v`` (``D = n.n``, ``sN = n.(v x w)``,
``tN = n.(u x w)``) instead of ipctk's ``ac - b^2`` dot-product forms. They are equal in
exact arithmetic, but just above the parallel switch (sin^2 of the angle up to ~1e-10) the
dot-product forms are mostly rounding and occasionally pick a feature pair far from the
closest one (ipctk's distance then errs by up to ~1e3x). In that band the two may return
different types, and ours gives the segment distance; elsewhere the types agree.

Mollifier (Li et al. 2020): ``c = |(ea1-ea0) x (eb1-eb0)|^2``, ``m(c) = (2 - c/eps_x) c/eps_x``
for ``c < eps_x`` else 1; ``eps_x = 1e-3 |ea1-ea0|^2 |eb1-eb0|^2`` at rest.

Barrier: ``b(d) = -(d - dhat2)^2 ln(d / dhat2)`` on squared distances for 0 < d < dhat2,
0 for d >= dhat2, +inf for d <= 0; its derivatives are 0 outside (0, dhat2) (as ipctk).
"""

from __future__ import annotations

import math

import numpy as np

from idp._leaf import leaf_njit

# --------------------------------------------------------------------------------------
# constants and tables
# --------------------------------------------------------------------------------------

PP = 0
PL = 1
PPLANE = 2
LL = 3

#: rows of the stencil of each kind
STENCIL_SIZE = np.array([2, 3, 4, 4], dtype=np.int64)

# ipctk.PointTriangleDistanceType
P_T0 = 0
P_T1 = 1
P_T2 = 2
P_E0 = 3
P_E1 = 4
P_E2 = 5
P_T = 6

# ipctk.EdgeEdgeDistanceType
EA0_EB0 = 0
EA0_EB1 = 1
EA1_EB0 = 2
EA1_EB1 = 3
EA_EB0 = 4
EA_EB1 = 5
EA0_EB = 6
EA1_EB = 7
EA_EB = 8

PT_KIND = np.array([PP, PP, PP, PL, PL, PL, PPLANE], dtype=np.int64)
PT_LOCAL = np.array(
    [
        [0, 1, -1, -1],
        [0, 2, -1, -1],
        [0, 3, -1, -1],
        [0, 1, 2, -1],
        [0, 2, 3, -1],
        [0, 3, 1, -1],
        [0, 1, 2, 3],
    ],
    dtype=np.int64,
)

EE_KIND = np.array([PP, PP, PP, PP, PL, PL, PL, PL, LL], dtype=np.int64)
EE_LOCAL = np.array(
    [
        [0, 2, -1, -1],
        [0, 3, -1, -1],
        [1, 2, -1, -1],
        [1, 3, -1, -1],
        [2, 0, 1, -1],
        [3, 0, 1, -1],
        [0, 2, 3, -1],
        [1, 2, 3, -1],
        [0, 1, 2, 3],
    ],
    dtype=np.int64,
)

#: ipctk treats edges as parallel when |u x v|^2 < EE_PARALLEL_TOL |u|^2 |v|^2
EE_PARALLEL_TOL = 2.5e-16

#: mollifier threshold factor: eps_x = EE_MOLLIFIER_FACTOR |ea|^2 |eb|^2 (rest lengths)
EE_MOLLIFIER_FACTOR = 1e-3

# Closest-point parametrisation w = sum_V c_V x_V, c_V = _KAPPA[kind, V] + _DELTA[kind, V] . lam
_KAPPA = np.array(
    [
        [1.0, -1.0, 0.0, 0.0],  # PP: p - q
        [1.0, -1.0, 0.0, 0.0],  # PL: p - (1-t) e0 - t e1
        [1.0, -1.0, 0.0, 0.0],  # PPLANE: p - (1-u-v) t0 - u t1 - v t2
        [1.0, 0.0, -1.0, 0.0],  # LL: (1-s) ea0 + s ea1 - (1-t) eb0 - t eb1
    ]
)
_DELTA = np.array(
    [
        [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]],
        [[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]],
        [[0.0, 0.0], [1.0, 1.0], [-1.0, 0.0], [0.0, -1.0]],
        [[-1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, -1.0]],
    ]
)

# mollifier: c = |a x b|^2 with a = sum_V _MA[V] x_V = ea1 - ea0, b = sum_V _MB[V] x_V = eb1 - eb0
_MA = np.array([-1.0, 1.0, 0.0, 0.0])
_MB = np.array([0.0, 0.0, -1.0, 1.0])


# --------------------------------------------------------------------------------------
# closest-point data of each kind
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def _closest(kind, X):
    """(d, lam0, lam1, w, J columns a/b, G^{-1} entries) of the stencil, all as scalars.

    Returns (d, l0, l1, w0, w1, w2, ja0, ja1, ja2, jb0, jb1, jb2, gi00, gi01, gi11).
    """
    if kind == PP:
        w0 = X[0, 0] - X[1, 0]
        w1 = X[0, 1] - X[1, 1]
        w2 = X[0, 2] - X[1, 2]
        d = w0 * w0 + w1 * w1 + w2 * w2
        return d, 0.0, 0.0, w0, w1, w2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == PL:
        r0 = X[0, 0] - X[1, 0]
        r1 = X[0, 1] - X[1, 1]
        r2 = X[0, 2] - X[1, 2]
        u0 = X[2, 0] - X[1, 0]
        u1 = X[2, 1] - X[1, 1]
        u2 = X[2, 2] - X[1, 2]
        D = u0 * u0 + u1 * u1 + u2 * u2
        t = (r0 * u0 + r1 * u1 + r2 * u2) / D
        w0 = r0 - t * u0
        w1 = r1 - t * u1
        w2 = r2 - t * u2
        d = w0 * w0 + w1 * w1 + w2 * w2
        # J = dw/dt = -u, G = D
        return d, t, 0.0, w0, w1, w2, -u0, -u1, -u2, 0.0, 0.0, 0.0, 1.0 / D, 0.0, 0.0
    if kind == PPLANE:
        r0 = X[0, 0] - X[1, 0]
        r1 = X[0, 1] - X[1, 1]
        r2 = X[0, 2] - X[1, 2]
        a0 = X[2, 0] - X[1, 0]
        a1 = X[2, 1] - X[1, 1]
        a2 = X[2, 2] - X[1, 2]
        b0 = X[3, 0] - X[1, 0]
        b1 = X[3, 1] - X[1, 1]
        b2 = X[3, 2] - X[1, 2]
        sgn = 1.0
    else:  # LL: r = ea0 - eb0 (so that w = (r.n/D) n), a = ea1 - ea0, b = eb1 - eb0
        r0 = X[0, 0] - X[2, 0]
        r1 = X[0, 1] - X[2, 1]
        r2 = X[0, 2] - X[2, 2]
        a0 = X[1, 0] - X[0, 0]
        a1 = X[1, 1] - X[0, 1]
        a2 = X[1, 2] - X[0, 2]
        b0 = X[3, 0] - X[2, 0]
        b1 = X[3, 1] - X[2, 1]
        b2 = X[3, 2] - X[2, 2]
        sgn = -1.0
    n0 = a1 * b2 - a2 * b1
    n1 = a2 * b0 - a0 * b2
    n2 = a0 * b1 - a1 * b0
    D = n0 * n0 + n1 * n1 + n2 * n2
    s = r0 * n0 + r1 * n1 + r2 * n2
    invD = 1.0 / D
    d = s * s * invD
    k = s * invD
    w0 = k * n0
    w1 = k * n1
    w2 = k * n2
    aa = a0 * a0 + a1 * a1 + a2 * a2
    bb = b0 * b0 + b1 * b1 + b2 * b2
    ab = a0 * b0 + a1 * b1 + a2 * b2
    # parameters: r - w = sgn*(l0 a + l1 b') with b' = b (PPLANE) or -b (LL); cross with b, a
    rb0 = r1 * b2 - r2 * b1
    rb1 = r2 * b0 - r0 * b2
    rb2 = r0 * b1 - r1 * b0
    ra0 = r1 * a2 - r2 * a1
    ra1 = r2 * a0 - r0 * a2
    ra2 = r0 * a1 - r1 * a0
    l0 = sgn * (rb0 * n0 + rb1 * n1 + rb2 * n2) * invD
    l1 = -(ra0 * n0 + ra1 * n1 + ra2 * n2) * invD
    # J columns: PPLANE (-a, -b); LL (a, -b). G = J^T J, det G = D
    return (
        d,
        l0,
        l1,
        w0,
        w1,
        w2,
        -sgn * a0,
        -sgn * a1,
        -sgn * a2,
        -b0,
        -b1,
        -b2,
        bb * invD,
        -sgn * ab * invD,
        aa * invD,
    )


@leaf_njit(error_model="numpy")
def _mirror_upper(H, m):
    for i in range(m):
        for j in range(i + 1, m):
            H[j, i] = H[i, j]


# --------------------------------------------------------------------------------------
# public distance kernels
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def edge_cross(X, i0, i1, j0, j1):
    """a = X[i1] − X[i0], b = X[j1] − X[j0] and n = a × b, as nine scalars (a, b, n)."""
    a0 = X[i1, 0] - X[i0, 0]
    a1 = X[i1, 1] - X[i0, 1]
    a2 = X[i1, 2] - X[i0, 2]
    b0 = X[j1, 0] - X[j0, 0]
    b1 = X[j1, 1] - X[j0, 1]
    b2 = X[j1, 2] - X[j0, 2]
    n0 = a1 * b2 - a2 * b1
    n1 = a2 * b0 - a0 * b2
    n2 = a0 * b1 - a1 * b0
    return a0, a1, a2, b0, b1, b2, n0, n1, n2


@leaf_njit(error_model="numpy")
def sq_distance(kind, X):
    """Squared distance of the stencil X (rows in stencil order) of the given kind."""
    if kind == PP:
        w0 = X[0, 0] - X[1, 0]
        w1 = X[0, 1] - X[1, 1]
        w2 = X[0, 2] - X[1, 2]
        return w0 * w0 + w1 * w1 + w2 * w2
    if kind == PL:
        r0 = X[0, 0] - X[1, 0]
        r1 = X[0, 1] - X[1, 1]
        r2 = X[0, 2] - X[1, 2]
        u0 = X[2, 0] - X[1, 0]
        u1 = X[2, 1] - X[1, 1]
        u2 = X[2, 2] - X[1, 2]
        t = (r0 * u0 + r1 * u1 + r2 * u2) / (u0 * u0 + u1 * u1 + u2 * u2)
        w0 = r0 - t * u0
        w1 = r1 - t * u1
        w2 = r2 - t * u2
        return w0 * w0 + w1 * w1 + w2 * w2
    if kind == PPLANE:  # normal of the plane through X[1], X[2], X[3]
        o = 1
        _a0, _a1, _a2, _b0, _b1, _b2, n0, n1, n2 = edge_cross(X, 1, 2, 1, 3)
    else:  # common normal of the lines X[0]X[1] and X[2]X[3]
        o = 2
        _a0, _a1, _a2, _b0, _b1, _b2, n0, n1, n2 = edge_cross(X, 0, 1, 2, 3)
    s = (X[0, 0] - X[o, 0]) * n0 + (X[0, 1] - X[o, 1]) * n1 + (X[0, 2] - X[o, 2]) * n2
    return s * s / (n0 * n0 + n1 * n1 + n2 * n2)


@leaf_njit(error_model="numpy")
def sq_distance_gradient(kind, X, g):
    """Write the gradient (length 3k, vertex-major) into g[:3k]; return the squared distance."""
    d, l0, l1, w0, w1, w2, _a0, _a1, _a2, _b0, _b1, _b2, _g0, _g1, _g2 = _closest(kind, X)
    nv = STENCIL_SIZE[kind]
    for V in range(nv):
        c2 = 2.0 * (_KAPPA[kind, V] + _DELTA[kind, V, 0] * l0 + _DELTA[kind, V, 1] * l1)
        g[3 * V] = c2 * w0
        g[3 * V + 1] = c2 * w1
        g[3 * V + 2] = c2 * w2
    return d


@leaf_njit(error_model="numpy")
def sq_distance_hessian(kind, X, g, H):
    """Gradient into g[:3k], exactly symmetric Hessian into H[:3k, :3k]; return the squared distance.

    H[V, W] = 2 c_V c_W I - 2 Z_V G^{-1} Z_W^T (see the module docstring).
    """
    d, l0, l1, w0, w1, w2, ja0, ja1, ja2, jb0, jb1, jb2, gi00, gi01, gi11 = _closest(kind, X)
    nv = STENCIL_SIZE[kind]
    for V in range(nv):
        dv0 = _DELTA[kind, V, 0]
        dv1 = _DELTA[kind, V, 1]
        cv = _KAPPA[kind, V] + dv0 * l0 + dv1 * l1
        rv = 3 * V
        g[rv] = 2.0 * cv * w0
        g[rv + 1] = 2.0 * cv * w1
        g[rv + 2] = 2.0 * cv * w2
        # Z_V columns and Y_V = 2 Z_V G^{-1}
        za0 = cv * ja0 + w0 * dv0
        za1 = cv * ja1 + w1 * dv0
        za2 = cv * ja2 + w2 * dv0
        zb0 = cv * jb0 + w0 * dv1
        zb1 = cv * jb1 + w1 * dv1
        zb2 = cv * jb2 + w2 * dv1
        ya0 = 2.0 * (za0 * gi00 + zb0 * gi01)
        ya1 = 2.0 * (za1 * gi00 + zb1 * gi01)
        ya2 = 2.0 * (za2 * gi00 + zb2 * gi01)
        yb0 = 2.0 * (za0 * gi01 + zb0 * gi11)
        yb1 = 2.0 * (za1 * gi01 + zb1 * gi11)
        yb2 = 2.0 * (za2 * gi01 + zb2 * gi11)
        for W in range(V, nv):
            dw0 = _DELTA[kind, W, 0]
            dw1 = _DELTA[kind, W, 1]
            cw = _KAPPA[kind, W] + dw0 * l0 + dw1 * l1
            xa0 = cw * ja0 + w0 * dw0
            xa1 = cw * ja1 + w1 * dw0
            xa2 = cw * ja2 + w2 * dw0
            xb0 = cw * jb0 + w0 * dw1
            xb1 = cw * jb1 + w1 * dw1
            xb2 = cw * jb2 + w2 * dw1
            cc = 2.0 * cv * cw
            cw3 = 3 * W
            H[rv, cw3] = cc - (ya0 * xa0 + yb0 * xb0)
            H[rv, cw3 + 1] = -(ya0 * xa1 + yb0 * xb1)
            H[rv, cw3 + 2] = -(ya0 * xa2 + yb0 * xb2)
            H[rv + 1, cw3] = -(ya1 * xa0 + yb1 * xb0)
            H[rv + 1, cw3 + 1] = cc - (ya1 * xa1 + yb1 * xb1)
            H[rv + 1, cw3 + 2] = -(ya1 * xa2 + yb1 * xb2)
            H[rv + 2, cw3] = -(ya2 * xa0 + yb2 * xb0)
            H[rv + 2, cw3 + 1] = -(ya2 * xa1 + yb2 * xb1)
            H[rv + 2, cw3 + 2] = cc - (ya2 * xa2 + yb2 * xb2)
    _mirror_upper(H, 3 * nv)
    return d


@leaf_njit(error_model="numpy")
def gather_stencil(local_ids, row, Y, X):
    """X[i] = Y[local_ids[row, i]] for the non-negative ids of that row (of PT_LOCAL / EE_LOCAL or a collision
    set's local ids); return the count. The table and its row, not the row view ``local_ids[row]``: a view costs
    two atomic reference-count updates, on a cache line the threads share when the table is shared."""
    k = 0
    live = True  # up to the first negative id (no ``break``: see the module docstring)
    for i in range(local_ids.shape[1]):
        v = local_ids[row, i]
        if v < 0:
            live = False
        if live:
            X[k, 0] = Y[v, 0]
            X[k, 1] = Y[v, 1]
            X[k, 2] = Y[v, 2]
            k += 1
    return k


# --------------------------------------------------------------------------------------
# closest-feature classification
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def _edge_slab(X, ip, ii, ij, n0, n1, n2):
    """(s, |e|^2, h) of row ip w.r.t. the edge of rows ii -> ij of the stencil X: s = (p-ti).e,
    h = (p-ti).(e x n) (> 0: outer side)."""
    e0 = X[ij, 0] - X[ii, 0]
    e1 = X[ij, 1] - X[ii, 1]
    e2 = X[ij, 2] - X[ii, 2]
    r0 = X[ip, 0] - X[ii, 0]
    r1 = X[ip, 1] - X[ii, 1]
    r2 = X[ip, 2] - X[ii, 2]
    s = r0 * e0 + r1 * e1 + r2 * e2
    ee = e0 * e0 + e1 * e1 + e2 * e2
    h = r0 * (e1 * n2 - e2 * n1) + r1 * (e2 * n0 - e0 * n2) + r2 * (e0 * n1 - e1 * n0)
    return s, ee, h


@leaf_njit(error_model="numpy")
def _sq_dist_points(p, q):
    a = p[0] - q[0]
    b = p[1] - q[1]
    c = p[2] - q[2]
    return a * a + b * b + c * c


@leaf_njit(error_model="numpy")
def _sq_dist_rows(X, i, j):
    """Squared distance between rows i and j of X."""
    a = X[i, 0] - X[j, 0]
    b = X[i, 1] - X[j, 1]
    c = X[i, 2] - X[j, 2]
    return a * a + b * b + c * c


@leaf_njit(error_model="numpy")
def _degenerate_triangle_type(X):
    """Collinear triangle (rows 1–3 of the stencil X, the point row 0): closest of the three segments
    (point-segment classification)."""
    best = np.inf
    best_type = P_T0
    for k in range(3):
        ia = 1 + k  # the edge t_k -> t_(k+1)
        ib = 1 + (k + 1) % 3
        e0 = X[ib, 0] - X[ia, 0]
        e1 = X[ib, 1] - X[ia, 1]
        e2 = X[ib, 2] - X[ia, 2]
        ee = e0 * e0 + e1 * e1 + e2 * e2
        s = (X[0, 0] - X[ia, 0]) * e0 + (X[0, 1] - X[ia, 1]) * e1 + (X[0, 2] - X[ia, 2]) * e2
        if s <= 0.0 or ee == 0.0:
            dist = _sq_dist_rows(X, 0, ia)
            typ = k  # vertex a of edge k is t_k
        elif s >= ee:
            dist = _sq_dist_rows(X, 0, ib)
            typ = (k + 1) % 3
        else:
            t = s / ee
            q0 = X[0, 0] - X[ia, 0] - t * e0
            q1 = X[0, 1] - X[ia, 1] - t * e1
            q2 = X[0, 2] - X[ia, 2] - t * e2
            dist = q0 * q0 + q1 * q1 + q2 * q2
            typ = P_E0 + k
        if dist < best:
            best = dist
            best_type = typ
    return best_type


@leaf_njit(error_model="numpy")
def point_triangle_type(X):
    """Closest feature of the triangle (rows 1, 2, 3 of the (4, 3) stencil X: t0, t1, t2) to the point (row 0),
    as ipctk.PointTriangleDistanceType. The stencil is read in place: row views (``X[0]``) passed to a call cost
    two atomic reference-count updates each in numba, which took half the time of the CCD bounds."""
    a0 = X[2, 0] - X[1, 0]
    a1 = X[2, 1] - X[1, 1]
    a2 = X[2, 2] - X[1, 2]
    b0 = X[3, 0] - X[1, 0]
    b1 = X[3, 1] - X[1, 1]
    b2 = X[3, 2] - X[1, 2]
    n0 = a1 * b2 - a2 * b1
    n1 = a2 * b0 - a0 * b2
    n2 = a0 * b1 - a1 * b0
    if n0 == 0.0 and n1 == 0.0 and n2 == 0.0:
        return _degenerate_triangle_type(X)
    s0, ee0, h0 = _edge_slab(X, 0, 1, 2, n0, n1, n2)
    s1, ee1, h1 = _edge_slab(X, 0, 2, 3, n0, n1, n2)
    s2, ee2, h2 = _edge_slab(X, 0, 3, 1, n0, n1, n2)
    # on the outer side of an edge with the projection inside it: that edge is closest
    # (the triangle lies in the inner half-plane of every edge)
    if h0 > 0.0 and 0.0 < s0 and s0 < ee0:
        return P_E0
    if h1 > 0.0 and 0.0 < s1 and s1 < ee1:
        return P_E1
    if h2 > 0.0 and 0.0 < s2 and s2 < ee2:
        return P_E2
    if h0 <= 0.0 and h1 <= 0.0 and h2 <= 0.0:
        return P_T
    # vertex Voronoi regions: beyond t_i along both adjacent edges
    if s0 <= 0.0 and s2 >= ee2:
        return P_T0
    if s1 <= 0.0 and s0 >= ee0:
        return P_T1
    if s2 <= 0.0 and s1 >= ee1:
        return P_T2
    # rounding left no region: nearest vertex
    d0 = _sq_dist_rows(X, 0, 1)
    d1 = _sq_dist_rows(X, 0, 2)
    d2 = _sq_dist_rows(X, 0, 3)
    if d0 <= d1 and d0 <= d2:
        return P_T0
    if d1 <= d2:
        return P_T1
    return P_T2


@leaf_njit(error_model="numpy")
def _edge_edge_parallel_type(X):
    """Parallel edges (rows 0, 1: edge A; rows 2, 3: edge B of the stencil X): project eb0, eb1 onto edge A
    (parameters alpha, beta; A = [0, 1])."""
    u0 = X[1, 0] - X[0, 0]
    u1 = X[1, 1] - X[0, 1]
    u2 = X[1, 2] - X[0, 2]
    a = u0 * u0 + u1 * u1 + u2 * u2
    alpha = ((X[2, 0] - X[0, 0]) * u0 + (X[2, 1] - X[0, 1]) * u1 + (X[2, 2] - X[0, 2]) * u2) / a
    beta = ((X[3, 0] - X[0, 0]) * u0 + (X[3, 1] - X[0, 1]) * u1 + (X[3, 2] - X[0, 2]) * u2) / a
    if 0.0 <= alpha and alpha <= 1.0:
        return EA_EB0
    if 0.0 <= beta and beta <= 1.0:
        return EA_EB1
    if alpha < 0.0 and beta < 0.0:  # B entirely before ea0
        return EA0_EB0 if alpha >= beta else EA0_EB1
    if alpha > 1.0 and beta > 1.0:  # B entirely after ea1
        return EA1_EB0 if alpha <= beta else EA1_EB1
    # B covers A: the endpoint of A on eb0's side
    return EA0_EB if alpha < 0.0 else EA1_EB


@leaf_njit(error_model="numpy")
def edge_edge_type(X):
    """Closest feature pair of the segments of rows (0, 1) and (2, 3) of the (4, 3) stencil X (ea0, ea1, eb0,
    eb1), as ipctk.EdgeEdgeDistanceType; the stencil is read in place (see :func:`point_triangle_type`)."""
    u0 = X[1, 0] - X[0, 0]
    u1 = X[1, 1] - X[0, 1]
    u2 = X[1, 2] - X[0, 2]
    v0 = X[3, 0] - X[2, 0]
    v1 = X[3, 1] - X[2, 1]
    v2 = X[3, 2] - X[2, 2]
    w0 = X[0, 0] - X[2, 0]
    w1 = X[0, 1] - X[2, 1]
    w2 = X[0, 2] - X[2, 2]
    a = u0 * u0 + u1 * u1 + u2 * u2
    b = u0 * v0 + u1 * v1 + u2 * v2
    c = v0 * v0 + v1 * v1 + v2 * v2
    d = u0 * w0 + u1 * w1 + u2 * w2
    e = v0 * w0 + v1 * w1 + v2 * w2
    if a == 0.0 and c == 0.0:
        return EA0_EB0
    if a == 0.0:
        return EA0_EB
    if c == 0.0:
        return EA_EB0
    n0 = u1 * v2 - u2 * v1
    n1 = u2 * v0 - u0 * v2
    n2 = u0 * v1 - u1 * v0
    if n0 * n0 + n1 * n1 + n2 * n2 < EE_PARALLEL_TOL * a * c:
        return _edge_edge_parallel_type(X)
    # f(s, t) = |w + s u - t v|^2 is strictly convex. Line optimum: s* = sN / D, t* = tN / D
    # with D = ac - b^2, sN = be - cd, tN = ae - bd, evaluated through Lagrange's identity as
    # D = n.n, sN = n.(v x w), tN = n.(u x w) (n = u x v): for nearly parallel edges the
    # dot-product forms cancel to rounding noise and can pick a far-off feature pair.
    # Clamping s first to [0, 1] gives the optimum over the strip; if the matching t leaves
    # [0, 1], the box optimum lies on that t edge, and s is re-solved there.
    D = n0 * n0 + n1 * n1 + n2 * n2
    sN = n0 * (v1 * w2 - v2 * w1) + n1 * (v2 * w0 - v0 * w2) + n2 * (v0 * w1 - v1 * w0)
    if sN <= 0.0:  # s = 0, t = e / c
        tN = e
        tD = c
        dflt = EA0_EB
    elif sN >= D:  # s = 1, t = (e + b) / c
        tN = e + b
        tD = c
        dflt = EA1_EB
    else:
        tN = n0 * (u1 * w2 - u2 * w1) + n1 * (u2 * w0 - u0 * w2) + n2 * (u0 * w1 - u1 * w0)
        tD = D
        dflt = EA_EB
    if tN <= 0.0:  # t = 0: s = -d / a clamped
        if -d <= 0.0:
            return EA0_EB0
        if -d >= a:
            return EA1_EB0
        return EA_EB0
    if tN >= tD:  # t = 1: s = (b - d) / a clamped
        if -d + b <= 0.0:
            return EA0_EB1
        if -d + b >= a:
            return EA1_EB1
        return EA_EB1
    return dflt


# --------------------------------------------------------------------------------------
# edge-edge mollifier
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def ee_mollifier_threshold(ea0_rest, ea1_rest, eb0_rest, eb1_rest):
    """eps_x = 1e-3 |ea1 - ea0|^2 |eb1 - eb0|^2 (rest positions)."""
    la = _sq_dist_points(ea1_rest, ea0_rest)
    lb = _sq_dist_points(eb1_rest, eb0_rest)
    return EE_MOLLIFIER_FACTOR * la * lb


@leaf_njit(error_model="numpy")
def ee_mollifier(X, eps_x):
    """m(c), c = |(ea1 - ea0) x (eb1 - eb0)|^2; X rows ea0, ea1, eb0, eb1."""
    _a0, _a1, _a2, _b0, _b1, _b2, n0, n1, n2 = edge_cross(X, 0, 1, 2, 3)
    c = n0 * n0 + n1 * n1 + n2 * n2
    if c < eps_x:
        q = c / eps_x
        return (2.0 - q) * q
    return 1.0


@leaf_njit(error_model="numpy")
def ee_mollifier_gradient(X, eps_x, g):
    """Gradient of m into g[:12] (zero when c >= eps_x); return m."""
    a0, a1, a2, b0, b1, b2, n0, n1, n2 = edge_cross(X, 0, 1, 2, 3)
    c = n0 * n0 + n1 * n1 + n2 * n2
    if c >= eps_x:
        for i in range(12):
            g[i] = 0.0
        return 1.0
    q = c / eps_x
    m1 = 2.0 * (1.0 - q) / eps_x  # dm/dc
    # dc/dx_V = 2 p_V x n, p_V = MA_V b - MB_V a
    for V in range(4):
        pa = _MA[V]
        pb = _MB[V]
        p0 = pa * b0 - pb * a0
        p1 = pa * b1 - pb * a1
        p2 = pa * b2 - pb * a2
        k = 2.0 * m1
        g[3 * V] = k * (p1 * n2 - p2 * n1)
        g[3 * V + 1] = k * (p2 * n0 - p0 * n2)
        g[3 * V + 2] = k * (p0 * n1 - p1 * n0)
    return (2.0 - q) * q


@leaf_njit(error_model="numpy")
def ee_mollifier_hessian(X, eps_x, g, H):
    """Gradient into g[:12], Hessian into H[:12, :12] (zero when c >= eps_x); return m.

    m'' = -2 / eps_x^2, m' = 2 (1 - c/eps_x) / eps_x;
    d^2c/dx_V dx_W = 2 [(p_V.p_W) I - p_V p_W^T - 2 k_VW [n]x],  k_VW = MA_V MB_W - MB_V MA_W.
    """
    a0, a1, a2, b0, b1, b2, n0, n1, n2 = edge_cross(X, 0, 1, 2, 3)
    c = n0 * n0 + n1 * n1 + n2 * n2
    if c >= eps_x:
        for i in range(12):
            g[i] = 0.0
            for j in range(12):
                H[i, j] = 0.0
        return 1.0
    q = c / eps_x
    m1 = 2.0 * (1.0 - q) / eps_x
    m2 = -2.0 / (eps_x * eps_x)
    # gradient of c, stored (scaled by m1) straight into g
    for V in range(4):
        pa = _MA[V]
        pb = _MB[V]
        p0 = pa * b0 - pb * a0
        p1 = pa * b1 - pb * a1
        p2 = pa * b2 - pb * a2
        g[3 * V] = 2.0 * m1 * (p1 * n2 - p2 * n1)
        g[3 * V + 1] = 2.0 * m1 * (p2 * n0 - p0 * n2)
        g[3 * V + 2] = 2.0 * m1 * (p0 * n1 - p1 * n0)
    # H = m'' dc dc^T + m' d^2c (dc recomputed unscaled: m' may be 0)
    k2 = 2.0 * m1
    for V in range(4):
        pva = _MA[V]
        pvb = _MB[V]
        pv0 = pva * b0 - pvb * a0
        pv1 = pva * b1 - pvb * a1
        pv2 = pva * b2 - pvb * a2
        cv0 = 2.0 * (pv1 * n2 - pv2 * n1)
        cv1 = 2.0 * (pv2 * n0 - pv0 * n2)
        cv2 = 2.0 * (pv0 * n1 - pv1 * n0)
        e0 = m2 * cv0
        e1 = m2 * cv1
        e2 = m2 * cv2
        rv = 3 * V
        for W in range(V, 4):
            pwa = _MA[W]
            pwb = _MB[W]
            pw0 = pwa * b0 - pwb * a0
            pw1 = pwa * b1 - pwb * a1
            pw2 = pwa * b2 - pwb * a2
            cw0 = 2.0 * (pw1 * n2 - pw2 * n1)
            cw1 = 2.0 * (pw2 * n0 - pw0 * n2)
            cw2 = 2.0 * (pw0 * n1 - pw1 * n0)
            pp = pv0 * pw0 + pv1 * pw1 + pv2 * pw2
            kx = 2.0 * (pva * pwb - pvb * pwa)  # coefficient of [n]x
            # m' * 2 [(pp) I - p_V p_W^T - kx [n]x] + m'' dc_V dc_W^T
            rw = 3 * W
            H[rv, rw] = k2 * (pp - pv0 * pw0) + e0 * cw0
            H[rv, rw + 1] = k2 * (-pv0 * pw1 + kx * n2) + e0 * cw1
            H[rv, rw + 2] = k2 * (-pv0 * pw2 - kx * n1) + e0 * cw2
            H[rv + 1, rw] = k2 * (-pv1 * pw0 - kx * n2) + e1 * cw0
            H[rv + 1, rw + 1] = k2 * (pp - pv1 * pw1) + e1 * cw1
            H[rv + 1, rw + 2] = k2 * (-pv1 * pw2 + kx * n0) + e1 * cw2
            H[rv + 2, rw] = k2 * (-pv2 * pw0 + kx * n1) + e2 * cw0
            H[rv + 2, rw + 1] = k2 * (-pv2 * pw1 - kx * n0) + e2 * cw1
            H[rv + 2, rw + 2] = k2 * (pp - pv2 * pw2) + e2 * cw2
    _mirror_upper(H, np.int64(12))  # not a literal: the same compiled _mirror_upper as sq_distance_hessian
    return (2.0 - q) * q


# --------------------------------------------------------------------------------------
# barrier (on squared distances)
# --------------------------------------------------------------------------------------


@leaf_njit(error_model="numpy")
def barrier(d, dhat2):
    """b(d) = -(d - dhat2)^2 ln(d / dhat2) for 0 < d < dhat2; 0 for d >= dhat2; +inf for d <= 0."""
    if d <= 0.0:
        return np.inf
    if d >= dhat2:
        return 0.0
    t = d - dhat2
    return -t * t * math.log(d / dhat2)


@leaf_njit(error_model="numpy")
def barrier_first_derivative(d, dhat2):
    """b'(d) = (dhat2 - d) (2 ln(d / dhat2) - dhat2 / d + 1) on (0, dhat2), else 0."""
    if d <= 0.0 or d >= dhat2:
        return 0.0
    return (dhat2 - d) * (2.0 * math.log(d / dhat2) - dhat2 / d + 1.0)


@leaf_njit(error_model="numpy")
def barrier_second_derivative(d, dhat2):
    """b''(d) = (dhat2 / d + 2) dhat2 / d - 2 ln(d / dhat2) - 3 on (0, dhat2), else 0."""
    if d <= 0.0 or d >= dhat2:
        return 0.0
    x = dhat2 / d
    return (x + 2.0) * x - 2.0 * math.log(d / dhat2) - 3.0
