"""Checks of the numba distance / mollifier / barrier kernels against finite differences,
ipctk 1.6.1 and independent brute-force segment/triangle distances."""

import ipctk
import numpy as np
import pytest

from idp.contact import _distance_kernels as K

PTT = ipctk.PointTriangleDistanceType
EET = ipctk.EdgeEdgeDistanceType

KINDS = [K.PP, K.PL, K.PPLANE, K.LL]
KIND_NAMES = {K.PP: "PP", K.PL: "PL", K.PPLANE: "PPLANE", K.LL: "LL"}

# ipctk functions of each kind take the stencil rows in our stencil order
IPCTK_REF = {
    K.PP: (ipctk.point_point_distance, ipctk.point_point_distance_gradient, ipctk.point_point_distance_hessian),
    K.PL: (ipctk.point_line_distance, ipctk.point_line_distance_gradient, ipctk.point_line_distance_hessian),
    K.PPLANE: (ipctk.point_plane_distance, ipctk.point_plane_distance_gradient, ipctk.point_plane_distance_hessian),
    K.LL: (ipctk.line_line_distance, ipctk.line_line_distance_gradient, ipctk.line_line_distance_hessian),
}


def well_conditioned_stencil(kind, rng):
    """Random stencil whose distance is smooth and not tiny: long edges, fat triangles, skew lines."""
    k = K.STENCIL_SIZE[kind]
    while True:
        X = rng.standard_normal((k, 3))
        if kind == K.PP:
            ok = np.linalg.norm(X[0] - X[1]) > 0.3
        elif kind == K.PL:
            u = X[2] - X[1]
            ok = np.linalg.norm(u) > 0.5 and np.linalg.norm(np.cross(X[0] - X[1], u)) / np.linalg.norm(u) > 0.3
        else:
            if kind == K.PPLANE:
                a, b, r = X[2] - X[1], X[3] - X[1], X[0] - X[1]
            else:
                a, b, r = X[1] - X[0], X[3] - X[2], X[2] - X[0]
            n = np.cross(a, b)
            ok = (
                np.linalg.norm(n) > 0.3 * np.linalg.norm(a) * np.linalg.norm(b)
                and min(np.linalg.norm(a), np.linalg.norm(b)) > 0.5
                and abs(r @ n) / np.linalg.norm(n) > 0.3
            )
        if ok:
            return X


def kernel_all(kind, X):
    k = K.STENCIL_SIZE[kind]
    g = np.zeros(12)
    H = np.zeros((12, 12))
    d = K.sq_distance_hessian(kind, X, g, H)
    return d, g[: 3 * k].copy(), H[: 3 * k, : 3 * k].copy()


def kernel_grad(kind, X):
    g = np.zeros(12)
    K.sq_distance_gradient(kind, X, g)
    return g[: 3 * K.STENCIL_SIZE[kind]].copy()


def central_fd(f, X, h):
    """Central differences of f (scalar or array valued) w.r.t. the flattened X."""
    flat = X.ravel()
    cols = []
    for i in range(flat.size):
        xp, xm = flat.copy(), flat.copy()
        xp[i] += h
        xm[i] -= h
        cols.append((np.asarray(f(xp.reshape(X.shape))) - np.asarray(f(xm.reshape(X.shape)))) / (2 * h))
    return np.array(cols)


# --------------------------------------------------------------------------------------
# distances: finite differences and ipctk
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", KINDS, ids=lambda k: KIND_NAMES[k])
def test_distance_derivatives_match_finite_differences(kind, seed):
    rng = np.random.default_rng(100 * kind + seed)
    for _ in range(3):
        X = well_conditioned_stencil(kind, rng)
        d, g, H = kernel_all(kind, X)
        assert d == pytest.approx(K.sq_distance(kind, X), rel=1e-13)
        g2 = np.zeros(12)
        assert K.sq_distance_gradient(kind, X, g2) == pytest.approx(d, rel=1e-13)
        np.testing.assert_allclose(g2[: g.size], g, rtol=1e-13, atol=1e-13)

        g_fd = central_fd(lambda Y: K.sq_distance(kind, Y), X, 1e-6)
        np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-7 * np.abs(g).max())
        H_fd = central_fd(lambda Y: kernel_grad(kind, Y), X, 1e-6)
        np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-6 * np.abs(H).max())
        assert np.array_equal(H, H.T)  # exact: the lower triangle is a copy of the upper one


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: KIND_NAMES[k])
def test_distance_matches_ipctk(kind):
    rng = np.random.default_rng(7 + kind)
    f, fg, fh = IPCTK_REF[kind]
    k = K.STENCIL_SIZE[kind]
    for _ in range(60):
        X = rng.standard_normal((k, 3)) * 10.0 ** rng.uniform(-2, 2)
        d, g, H = kernel_all(kind, X)
        rd, rg, rh = f(*X), np.asarray(fg(*X)).ravel(), fh(*X)
        assert d == pytest.approx(rd, rel=1e-9)
        np.testing.assert_allclose(g, rg, rtol=0, atol=1e-9 * np.abs(rg).max())
        np.testing.assert_allclose(H, rh, rtol=0, atol=1e-9 * np.abs(rh).max())
        assert np.array_equal(H, H.T)  # exact: the lower triangle is a copy of the upper one


def test_hessian_writes_only_leading_block():
    rng = np.random.default_rng(3)
    for kind in (K.PP, K.PL):
        k3 = 3 * K.STENCIL_SIZE[kind]
        X = well_conditioned_stencil(kind, rng)
        g = np.full(12, 7.0)
        H = np.full((12, 12), 7.0)
        K.sq_distance_hessian(kind, X, g, H)
        assert np.all(g[k3:] == 7.0)
        assert np.all(H[k3:, :] == 7.0) and np.all(H[:, k3:] == 7.0)
        assert np.array_equal(H[:k3, :k3], H[:k3, :k3].T)


# --------------------------------------------------------------------------------------
# stencil tables and enum values
# --------------------------------------------------------------------------------------


def test_enum_values_match_ipctk():
    for name in ["P_T0", "P_T1", "P_T2", "P_E0", "P_E1", "P_E2", "P_T"]:
        assert getattr(K, name) == int(getattr(PTT, name))
    for name in ["EA0_EB0", "EA0_EB1", "EA1_EB0", "EA1_EB1", "EA_EB0", "EA_EB1", "EA0_EB", "EA1_EB", "EA_EB"]:
        assert getattr(K, name) == int(getattr(EET, name))


def stencil_value_and_gradient(kind_table, local_table, t, Y):
    """Distance of type t on the 4 local vertices Y and its gradient scattered to 12 entries."""
    kind, ids = kind_table[t], local_table[t]
    X = np.zeros((4, 3))
    n = K.gather_stencil(local_table, t, Y, X)
    assert n == K.STENCIL_SIZE[kind]
    X = X[:n]
    g = np.zeros(12)
    d = K.sq_distance_gradient(kind, X, g)
    full = np.zeros(12)
    for i, v in enumerate(ids[:n]):
        full[3 * v : 3 * v + 3] += g[3 * i : 3 * i + 3]
    return d, full


def test_stencil_tables_match_ipctk_forced_types():
    rng = np.random.default_rng(11)
    for _ in range(20):
        Y = rng.standard_normal((4, 3))
        for t in range(7):
            d, g = stencil_value_and_gradient(K.PT_KIND, K.PT_LOCAL, t, Y)
            assert d == pytest.approx(ipctk.point_triangle_distance(*Y, PTT(t)), rel=1e-10)
            rg = np.asarray(ipctk.point_triangle_distance_gradient(*Y, PTT(t))).ravel()
            np.testing.assert_allclose(g, rg, rtol=0, atol=1e-10 * np.abs(rg).max())
        for t in range(9):
            d, g = stencil_value_and_gradient(K.EE_KIND, K.EE_LOCAL, t, Y)
            assert d == pytest.approx(ipctk.edge_edge_distance(*Y, EET(t)), rel=1e-10)
            rg = np.asarray(ipctk.edge_edge_distance_gradient(*Y, EET(t))).ravel()
            np.testing.assert_allclose(g, rg, rtol=0, atol=1e-10 * np.abs(rg).max())


# --------------------------------------------------------------------------------------
# classification
# --------------------------------------------------------------------------------------


def brute_point_segment(p, a, b):
    e = b - a
    s = np.clip((p - a) @ e / (e @ e), 0.0, 1.0)
    q = p - a - s * e
    return q @ q


def brute_point_triangle(p, t0, t1, t2):
    a, b, r = t1 - t0, t2 - t0, p - t0
    G = np.array([[a @ a, a @ b], [a @ b, b @ b]])
    u, v = np.linalg.solve(G, [r @ a, r @ b])
    cands = [brute_point_segment(p, t0, t1), brute_point_segment(p, t1, t2), brute_point_segment(p, t2, t0)]
    if u >= 0 and v >= 0 and u + v <= 1:
        q = r - u * a - v * b
        cands.append(q @ q)
    return min(cands)


def brute_segment_segment(ea0, ea1, eb0, eb1):
    """min over [0,1]^2 of |ea0 + s u - eb0 - t v|^2: interior stationary point and the 4 box edges."""
    u, v, w = ea1 - ea0, eb1 - eb0, ea0 - eb0
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w

    def f(s, t):
        q = w + s * u - t * v
        return q @ q

    cands = []
    for s in (0.0, 1.0):
        cands.append(f(s, np.clip((e + s * b) / c, 0.0, 1.0)))
    for t in (0.0, 1.0):
        cands.append(f(np.clip((t * b - d) / a, 0.0, 1.0), t))
    D = a * c - b * b
    if D > 1e-10 * a * c:
        s, t = (b * e - c * d) / D, (a * e - b * d) / D
        if 0 <= s <= 1 and 0 <= t <= 1:
            cands.append(f(s, t))
    return min(cands)


def typed_distance(kind_table, local_table, t, Y):
    ids = local_table[t]
    return K.sq_distance(kind_table[t], Y[ids[ids >= 0]])


def point_triangle_configs(rng, n):
    out = []
    for i in range(n):
        t0, t1, t2 = rng.standard_normal((3, 3))
        mode = i % 4
        if mode == 0:
            p = 2.0 * rng.standard_normal(3)
        elif mode == 1:  # near an edge, on either side, slightly off the plane
            A, B = [(t0, t1), (t1, t2), (t2, t0)][rng.integers(3)]
            nrm = np.cross(t1 - t0, t2 - t0)
            nrm /= np.linalg.norm(nrm)
            perp = np.cross(B - A, nrm)
            perp /= np.linalg.norm(perp)
            p = (
                A
                + rng.uniform(-0.2, 1.2) * (B - A)
                + rng.choice([-1, 1]) * 10 ** rng.uniform(-12, -1) * perp
                + rng.choice([-1, 1]) * 10 ** rng.uniform(-12, 0) * nrm
            )
        elif mode == 2:  # near a vertex
            p = [t0, t1, t2][rng.integers(3)] + 10 ** rng.uniform(-12, -1) * rng.standard_normal(3)
        else:  # obtuse slivers
            t2 = t0 + rng.uniform(-0.5, 1.5) * (t1 - t0) + 10 ** rng.uniform(-5, -1) * rng.standard_normal(3)
            p = rng.standard_normal(3)
        out.append(np.array([p, t0, t1, t2]))
    return out


def edge_edge_configs(rng, n):
    out = []
    for i in range(n):
        ea0, ea1, eb0 = rng.standard_normal((3, 3))
        mode = i % 5
        if mode == 0:
            eb1 = rng.standard_normal(3)
        elif mode == 1:  # nearly parallel, overlapping or not
            eb0 = ea0 + rng.uniform(-2, 2) * (ea1 - ea0) + 0.3 * rng.standard_normal(3)
            eb1 = eb0 + rng.uniform(-2, 2) * (ea1 - ea0) + 10 ** rng.uniform(-12, -2) * rng.standard_normal(3)
        elif mode == 2:  # around ipctk's parallel threshold (sin^2 ~ 2.5e-16)
            eb1 = eb0 + rng.uniform(-2, 2) * (ea1 - ea0) + 10 ** rng.uniform(-9, -7) * rng.standard_normal(3)
        elif mode == 3:  # nearly intersecting
            s, t = rng.uniform(-0.1, 1.1, 2)
            dirb = rng.standard_normal(3)
            eb0 = ea0 + s * (ea1 - ea0) - t * dirb + 1e-6 * rng.standard_normal(3)
            eb1 = eb0 + dirb
        else:  # exactly parallel on an integer grid (endpoint projections may coincide)
            ea0 = rng.integers(-4, 5, 3).astype(float)
            u = rng.integers(-3, 4, 3).astype(float)
            if not u.any():
                u[0] = 1.0
            ea1 = ea0 + u
            eb0 = ea0 + rng.integers(-4, 5, 3).astype(float)
            eb1 = eb0 + rng.choice([-2, -1, -0.5, 0.5, 1, 2, 3]) * u
        out.append(np.array([ea0, ea1, eb0, eb1]))
    return out


def test_point_triangle_type_matches_ipctk():
    rng = np.random.default_rng(21)
    configs = point_triangle_configs(rng, 2000)
    mismatches = 0
    for Y in configs:
        t = K.point_triangle_type(np.asarray(Y, dtype=float))
        tr = int(ipctk.point_triangle_distance_type(*Y))
        d = typed_distance(K.PT_KIND, K.PT_LOCAL, t, Y)
        dr = ipctk.point_triangle_distance(*Y)
        if t != tr:  # only allowed on region boundaries, where the distances agree
            mismatches += 1
            assert d == pytest.approx(typed_distance(K.PT_KIND, K.PT_LOCAL, tr, Y), rel=1e-8, abs=1e-14)
        assert d == pytest.approx(dr, rel=1e-6, abs=1e-14)
        assert d == pytest.approx(brute_point_triangle(*Y), rel=1e-6, abs=1e-13)
    assert mismatches <= len(configs) // 200


def test_edge_edge_type_matches_ipctk():
    rng = np.random.default_rng(22)
    configs = edge_edge_configs(rng, 2500)
    mismatches = 0
    for Y in configs:
        t = K.edge_edge_type(np.asarray(Y, dtype=float))
        tr = int(ipctk.edge_edge_distance_type(*Y))
        d = typed_distance(K.EE_KIND, K.EE_LOCAL, t, Y)
        if t != tr:
            mismatches += 1
            assert d == pytest.approx(typed_distance(K.EE_KIND, K.EE_LOCAL, tr, Y), rel=1e-8, abs=1e-14)
        assert d == pytest.approx(ipctk.edge_edge_distance(*Y), rel=1e-6, abs=1e-14)
        assert d == pytest.approx(brute_segment_segment(*Y), rel=1e-6, abs=1e-13)
    assert mismatches <= len(configs) // 200


def near_parallel_edges(rng, sin2, gap):
    """Edge B at angle asin(sqrt(sin2)) to edge A, offset `gap` across, with random overlap along A."""
    ea0 = rng.standard_normal(3)
    u = rng.standard_normal(3)
    w = np.cross(u, rng.standard_normal(3))
    w /= np.linalg.norm(w)
    v = rng.uniform(0.5, 2) * rng.choice([-1, 1]) * u + np.sqrt(sin2) * np.linalg.norm(u) * w
    eb0 = ea0 + rng.uniform(-2.5, 1.5) * u + gap * np.cross(u, w) / np.linalg.norm(u)
    return np.array([ea0, ea0 + u, eb0, eb0 + v])


def test_edge_edge_parallel_threshold_and_rule_match_ipctk():
    # sweep sin^2(angle) across ipctk's switch (2.5e-16): below it both use the parallel rule
    # (identical types); above it the regular rule's inputs are mostly rounding in a band up
    # to ~1e-10, where ipctk's ac - b^2 forms and our cross-product forms may pick different
    # (equally close) features: there only the distance is compared, with the true one
    rng = np.random.default_rng(5)
    n_par = n_reg = n_diff = 0
    for sin2 in np.geomspace(1e-17, 1e-13, 300):
        Y = near_parallel_edges(rng, sin2, 10 ** rng.uniform(-4, -1))
        t = K.edge_edge_type(np.asarray(Y, dtype=float))
        cr = np.cross(Y[1] - Y[0], Y[3] - Y[2])
        if cr @ cr < K.EE_PARALLEL_TOL * ((Y[1] - Y[0]) @ (Y[1] - Y[0])) * ((Y[3] - Y[2]) @ (Y[3] - Y[2])):
            n_par += 1
            assert t == K._edge_edge_parallel_type(np.asarray(Y, dtype=float)) == int(ipctk.edge_edge_distance_type(*Y))
        else:
            n_reg += 1
            n_diff += t != int(ipctk.edge_edge_distance_type(*Y))
        d = typed_distance(K.EE_KIND, K.EE_LOCAL, t, Y)
        assert d == pytest.approx(brute_segment_segment(*Y), rel=1e-4)
    assert n_par > 50 and n_reg > 50 and n_diff < 0.2 * n_reg
    # the parallel rule itself, on exactly parallel edges (integer grids: coinciding projections)
    for Y in edge_edge_configs(rng, 1000)[4::5]:
        assert K._edge_edge_parallel_type(np.asarray(Y, dtype=float)) == int(ipctk.edge_edge_distance_type(*Y))


def test_edge_edge_type_distance_is_exact_for_nearly_parallel_edges():
    # the rounding band above the parallel switch, with touching / slightly separated /
    # overlapping segments: the chosen feature pair must give the segment distance
    # (ipctk 1.6.1 errs by up to ~1e3x on a few of these; this is why sN, tN, D use n = u x v)
    rng = np.random.default_rng(6)
    for _ in range(1500):
        Y = near_parallel_edges(rng, 10 ** rng.uniform(-15.6, -9), 10 ** rng.uniform(-4, -1))
        d = typed_distance(K.EE_KIND, K.EE_LOCAL, K.edge_edge_type(np.asarray(Y, dtype=float)), Y)
        assert d == pytest.approx(brute_segment_segment(*Y), rel=1e-4)


def test_degenerate_edges_match_ipctk():
    z, x = np.zeros(3), np.array([1.0, 0, 0])
    for q in (np.array([0.3, 0.2, 1.0]), np.array([-2.0, 0.5, 0.1]), np.array([3.0, -1.0, 0.0])):
        assert K.edge_edge_type(np.array([q, q, z, x], dtype=float)) == int(ipctk.edge_edge_distance_type(q, q, z, x))
        assert K.edge_edge_type(np.array([z, x, q, q], dtype=float)) == int(ipctk.edge_edge_distance_type(z, x, q, q))
        assert K.edge_edge_type(np.array([z, z, q, q], dtype=float)) == int(ipctk.edge_edge_distance_type(z, z, q, q))


def test_degenerate_triangle_gives_closest_segment_feature():
    rng = np.random.default_rng(9)
    for _ in range(50):
        t0, d = rng.standard_normal((2, 3))
        t1, t2 = t0 + d, t0 + rng.choice([-1.5, -0.5, 0.5, 2.0]) * d
        p = rng.standard_normal(3)
        Y = np.array([p, t0, t1, t2])
        t = K.point_triangle_type(np.asarray(Y, dtype=float))
        assert t != K.P_T
        ref = min(brute_point_segment(p, a, b) for a, b in ((t0, t1), (t1, t2), (t2, t0)))
        assert typed_distance(K.PT_KIND, K.PT_LOCAL, t, Y) == pytest.approx(ref, rel=1e-9, abs=1e-14)


# --------------------------------------------------------------------------------------
# mollifier
# --------------------------------------------------------------------------------------


def mollifier_config(rng, active):
    X = rng.standard_normal((4, 3))
    if active:  # nearly parallel: c = |u x v|^2 <= 7.5e-5 |u|^4 < eps >= 2.5e-4 |u|^4
        u = X[1] - X[0]
        X[3] = X[2] + rng.choice([-1, 1]) * rng.uniform(0.5, 2) * u + 0.005 * np.linalg.norm(u) * rng.standard_normal(3)
    eps = K.ee_mollifier_threshold(*X)
    # a product of two sums of squares: relative error <= ~8 u in either implementation
    assert eps == pytest.approx(ipctk.edge_edge_mollifier_threshold(*X), rel=1e-14)
    return X, eps


@pytest.mark.parametrize("active", [True, False])
def test_mollifier_matches_ipctk(active):
    rng = np.random.default_rng(31 + active)
    for _ in range(40):
        X, eps = mollifier_config(rng, active)
        g = np.full(12, 9.0)
        H = np.full((12, 12), 9.0)
        m = K.ee_mollifier_hessian(X, eps, g, H)
        assert (m < 1.0) == active
        assert m == pytest.approx(ipctk.edge_edge_mollifier(*X, eps), rel=1e-12)
        # the three entry points evaluate the same formula; agreement to rounding is what matters
        assert K.ee_mollifier(X, eps) == pytest.approx(m, rel=1e-14)
        g2 = np.full(12, 9.0)
        assert K.ee_mollifier_gradient(X, eps, g2) == pytest.approx(m, rel=1e-14)
        rg = np.asarray(ipctk.edge_edge_mollifier_gradient(*X, eps)).ravel()
        rh = ipctk.edge_edge_mollifier_hessian(*X, eps)
        scale_g = max(np.abs(rg).max(), 1e-300)
        scale_h = max(np.abs(rh).max(), 1e-300)
        np.testing.assert_allclose(g, rg, rtol=0, atol=1e-10 * scale_g)
        np.testing.assert_allclose(g2, rg, rtol=0, atol=1e-10 * scale_g)
        np.testing.assert_allclose(H, rh, rtol=0, atol=1e-10 * scale_h)
        assert np.array_equal(H, H.T)  # exact: the lower triangle is a copy of the upper one


def test_mollifier_derivatives_match_finite_differences():
    rng = np.random.default_rng(41)
    for _ in range(6):
        X, eps = mollifier_config(rng, True)
        g = np.zeros(12)
        H = np.zeros((12, 12))
        m = K.ee_mollifier_hessian(X, eps, g, H)
        assert 0.0 < m < 0.95
        h = 1e-7

        def grad(Y):
            gg = np.zeros(12)
            K.ee_mollifier_gradient(Y, eps, gg)
            return gg

        g_fd = central_fd(lambda Y: K.ee_mollifier(Y, eps), X, h)
        np.testing.assert_allclose(g, g_fd, rtol=1e-5, atol=1e-6 * np.abs(g).max())
        H_fd = central_fd(grad, X, h)
        np.testing.assert_allclose(H, H_fd, rtol=1e-4, atol=1e-5 * np.abs(H).max())


# --------------------------------------------------------------------------------------
# barrier
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("dhat2", [1e-6, 1e-2, 1.0])
def test_barrier_matches_ipctk(dhat2):
    ds = np.concatenate([[-1.0, -1e-30, 0.0, dhat2, 2 * dhat2], dhat2 * np.geomspace(1e-8, 0.999, 40)])
    for d in ds:
        assert K.barrier(d, dhat2) == pytest.approx(ipctk.barrier(d, dhat2), rel=1e-12, abs=0)
        assert K.barrier_first_derivative(d, dhat2) == pytest.approx(
            ipctk.barrier_first_derivative(d, dhat2), rel=1e-12, abs=0
        )
        assert K.barrier_second_derivative(d, dhat2) == pytest.approx(
            ipctk.barrier_second_derivative(d, dhat2), rel=1e-12, abs=1e-15
        )
    assert K.barrier(0.0, dhat2) == np.inf and K.barrier(-1.0, dhat2) == np.inf


@pytest.mark.parametrize("dhat2", [1e-4, 1.0])
def test_barrier_derivatives_match_finite_differences(dhat2):
    for d in dhat2 * np.array([1e-3, 0.05, 0.3, 0.7, 0.99]):
        h = 1e-6 * d
        fd1 = (K.barrier(d + h, dhat2) - K.barrier(d - h, dhat2)) / (2 * h)
        fd2 = (K.barrier_first_derivative(d + h, dhat2) - K.barrier_first_derivative(d - h, dhat2)) / (2 * h)
        assert K.barrier_first_derivative(d, dhat2) == pytest.approx(fd1, rel=1e-6)
        assert K.barrier_second_derivative(d, dhat2) == pytest.approx(fd2, rel=1e-6)
