"""Tests of idp.energies.plasticity: the von Mises return mapping lands exactly on the (hardened) yield surface,
is isochoric and leaves sub-yield elements untouched; a pulled and released bar keeps a permanent stretch
where a purely elastic one springs back."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from idp.energies.elastic import ElasticEnergy
from idp.energies.plasticity import VonMisesPlasticity


def _rotation(d: int, rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(d, d)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def one_element(d: int, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest vertices, elements, deformed vertices) of one simplex deformed by F."""
    X = np.vstack([np.zeros(d), np.eye(d) + 0.1 * np.triu(np.ones((d, d)), 1)])
    T = np.arange(d + 1)[None]
    return X, T, X @ F.T


def dev_log_strain_norm(E: ElasticEnergy, x: np.ndarray) -> np.ndarray:
    sig = np.linalg.svd(E.deformation_gradients(x), compute_uv=False)
    eps = np.log(sig)
    return np.linalg.norm(eps - eps.mean(axis=1, keepdims=True), axis=1)


@pytest.mark.parametrize("d,model,hardening", list(itertools.product([3, 2], ["neo_hookean", "stvk"], [0.0, 5e3])))
def test_return_mapping_lands_on_the_yield_surface(d: int, model: str, hardening: float) -> None:
    rng = np.random.default_rng(1)
    F = _rotation(d, rng) @ np.diag([1.6, 0.8, 0.9][:d]) @ _rotation(d, rng).T
    X, T, x = one_element(d, F)
    E = ElasticEnergy(model, X, T, 1e4, 0.3)
    mu = E.mu[0]
    tau = 0.05 * 2 * mu  # yield at |dev eps| = 0.05
    P = VonMisesPlasticity(tau, hardening)
    before = dev_log_strain_norm(E, x)[0]
    assert before > 0.2
    J_before = np.linalg.det(E.deformation_gradients(x))
    Dm_before = np.linalg.inv(E.Dm_inv)
    assert P.apply(E, x) == 1
    assert P.plastic_strain is not None
    alpha = P.plastic_strain[0]
    after = dev_log_strain_norm(E, x)[0]
    # exactly on the (hardened) surface: 2 mu |dev eps| = tau + H alpha, and alpha = the strain removed
    assert after == pytest.approx((tau + hardening * alpha) / (2 * mu), rel=1e-12)
    assert P.yield_strain(E)[0] == pytest.approx(after, rel=1e-12)
    assert alpha == pytest.approx(before - after, rel=1e-12)
    if hardening:
        assert after > 0.05 * (1 + 1e-3)
    # isochoric: det F and the rest volume are kept; F_p = Dm' Dm⁻¹ is symmetric in the rest frame, det 1
    np.testing.assert_allclose(np.linalg.det(E.deformation_gradients(x)), J_before, rtol=1e-12)
    Fp = np.linalg.inv(E.Dm_inv[0]) @ np.linalg.inv(Dm_before[0])
    assert np.linalg.det(Fp) == pytest.approx(1.0, abs=1e-12)
    # the elastic part keeps F's singular vectors: F_e = U Σ_new Vᵀ, so F_e⁻¹ F = F_p is symmetric PD
    Fe = E.deformation_gradients(x)[0]
    Fp_from_F = np.linalg.solve(Fe, F)
    np.testing.assert_allclose(Fp_from_F, Fp_from_F.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(0.5 * (Fp_from_F + Fp_from_F.T)) > 0)
    # a second apply at the same shape: already on the surface, nothing yields
    Dm_inv = E.Dm_inv.copy()
    assert P.apply(E, x) == 0
    np.testing.assert_array_equal(E.Dm_inv, Dm_inv)
    assert P.plastic_strain[0] == alpha


@pytest.mark.parametrize("d", [3, 2])
def test_below_yield_nothing_changes(d: int) -> None:
    rng = np.random.default_rng(2)
    F = _rotation(d, rng) @ np.diag([1.02, 0.99, 1.0][:d]) @ _rotation(d, rng).T
    X, T, x = one_element(d, F)
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    E.set_rest_scale(1.01)
    Dm_inv = E.Dm_inv.copy()
    base = E.base_rest_frames.copy()
    P = VonMisesPlasticity(0.1 * 2 * E.mu[0], hardening=1e3)
    assert P.apply(E, x) == 0
    np.testing.assert_array_equal(E.Dm_inv, Dm_inv)
    np.testing.assert_array_equal(E.base_rest_frames, base)
    np.testing.assert_array_equal(P.plastic_strain, [0.0])
    # a pure volume change never yields (von Mises is deviatoric), however large
    assert P.apply(E, 3.0 * X) == 0


def test_mixed_mesh_yields_only_the_elements_over_the_limit_and_keeps_the_rest_transform() -> None:
    verts, tets = [], []
    stretches = [1.01, 1.5, 0.98, 2.0, 1.0]
    for i, s in enumerate(stretches):
        X, T, x = one_element(3, np.diag([s, 1.0, 1.0]))
        verts.append((X + 3.0 * i, x + 3.0 * i))
        tets.append(T[0] + 4 * i)
    X = np.vstack([v[0] for v in verts])
    x = np.vstack([v[1] for v in verts])
    T = np.array(tets)
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    # under a rest transform (growth) the plastic update goes into the base frames, the transform stays
    E.set_rest_scale(np.array([1.0, 1.1, 1.1]))
    x = x * np.array([1.0, 1.1, 1.1])
    Dm_inv = E.Dm_inv.copy()
    tau = 0.1 * 2 * E.mu[0]
    P = VonMisesPlasticity(np.full(len(T), tau))
    assert P.apply(E, x) == 2
    np.testing.assert_array_equal(P.last_yielded, [False, True, False, True, False])
    np.testing.assert_array_equal(E.Dm_inv[[0, 2, 4]], Dm_inv[[0, 2, 4]])
    np.testing.assert_allclose(dev_log_strain_norm(E, x)[[1, 3]], 0.1, rtol=1e-12)
    np.testing.assert_array_equal(E.rest_transform, np.diag([1.0, 1.1, 1.1]))
    assert P.plastic_strain is not None
    assert P.plastic_strain[3] > P.plastic_strain[1] > 0
    assert np.all(P.plastic_strain[[0, 2, 4]] == 0)


def test_inverted_elements_are_skipped() -> None:
    X, T, x = one_element(3, np.diag([2.0, 1.0, -1.0]))
    E = ElasticEnergy("arap", X, T, 1e4, 0.3)
    P = VonMisesPlasticity(1.0)
    assert P.apply(E, x) == 0
    np.testing.assert_array_equal(P.plastic_strain, [0.0])


def test_validation() -> None:
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="yield stress must be finite and > 0"):
            VonMisesPlasticity(bad)
    with pytest.raises(ValueError, match="yield stress"):
        VonMisesPlasticity(np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="hardening modulus must be finite and ≥ 0"):
        VonMisesPlasticity(1.0, hardening=-1.0)
    X, T, x = one_element(3, np.eye(3))
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    with pytest.raises(ValueError, match="has shape"):
        VonMisesPlasticity(np.array([1.0, 2.0])).apply(E, x)
    P = VonMisesPlasticity(1.0)
    P.apply(E, x)
    X2 = np.vstack([X, X + 3.0])
    E2 = ElasticEnergy("neo_hookean", X2, np.vstack([T, T + 4]), 1e4, 0.3)
    with pytest.raises(ValueError, match="one VonMisesPlasticity per body"):
        P.apply(E2, X2)


# ------------------------------------------------------------------ a bar pulled and released


def bar_mesh(nx: int = 6, length: float = 3.0, width: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A length x width x width bar along x: nx x 1 x 1 cubes, 6 tets each (positively oriented)."""
    gx = np.linspace(0.0, length, nx + 1)
    gw = np.array([0.0, width])
    X = np.stack(np.meshgrid(gx, gw, gw, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(X.shape[0]).reshape(nx + 1, 2, 2)
    tets = []
    for i in range(nx):
        for perm in itertools.permutations(range(3)):
            corner = np.zeros(3, int)
            path = [idx[i, 0, 0]]
            for ax in perm:
                corner[ax] = 1
                path.append(idx[i + corner[0], corner[1], corner[2]])
            tets.append(path)
    T = np.array(tets, dtype=np.int64)
    Dm = np.transpose(X[T[:, 1:]] - X[T[:, :1]], (0, 2, 1))
    neg = np.linalg.det(Dm) < 0
    T[neg, 0], T[neg, 1] = T[neg, 1].copy(), T[neg, 0].copy()
    return X, T


def minimise(E: ElasticEnergy, x: np.ndarray, free: np.ndarray, iters: int = 100) -> np.ndarray:
    """Projected Newton with backtracking and the inversion filter on the free DOFs (flat bool mask)."""
    x = x.ravel().copy()
    dofs = E.element_dofs()
    k = dofs.shape[1]
    rows = np.repeat(dofs, k, axis=1).ravel()
    cols = np.tile(dofs, (1, k)).ravel()
    n = x.size
    g0: float | None = None
    for _ in range(iters):
        f, g, H = E.value_gradient_hessian(x)
        g = np.where(free, g, 0.0)
        g0 = float(np.linalg.norm(g)) if g0 is None else g0
        if np.linalg.norm(g) <= 1e-10 * max(g0, 1.0):
            break
        A = sp.coo_matrix((H.ravel(), (rows, cols)), shape=(n, n)).tocsr()[free][:, free]
        dx = np.zeros(n)
        dx[free] = spla.spsolve(A.tocsc(), -g[free])
        alpha = min(1.0, 0.9 * E.max_step(x, dx))
        while E.value(x + alpha * dx) > f + 1e-4 * alpha * (g @ dx) and alpha > 1e-12:
            alpha *= 0.5
        x = x + alpha * dx
    return x.reshape(-1, E.dim)


@pytest.mark.parametrize("plastic", [False, True])
def test_bar_pulled_and_released_keeps_a_permanent_stretch_only_when_plastic(plastic: bool) -> None:
    X, T = bar_mesh()
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    P = VonMisesPlasticity(0.05 * 2 * E.mu[0]) if plastic else None
    left = X[:, 0] == 0.0
    right = X[:, 0] == X[:, 0].max()
    L = X[:, 0].max()
    x = X.copy()
    free_pulled = np.repeat(~(left | right), 3)
    # pull the right end to 1.6 L in steps; plasticity at the start of each step, as the stepper applies it
    for stretch in np.linspace(1.1, 1.6, 6):
        if P is not None:
            P.apply(E, x)
        x[:, 0] *= stretch * L / x[right, 0].max()  # affine initial guess keeps every tet positive
        x = minimise(E, x, free_pulled)
    for _ in range(3):  # hold: the flow settles
        if P is not None:
            P.apply(E, x)
        x = minimise(E, x, free_pulled)
    assert x[right, 0].max() == pytest.approx(1.6 * L)
    # release the right end (the left end stays clamped) and let the bar relax
    free_released = np.repeat(~left, 3)
    for _ in range(3):
        if P is not None:
            P.apply(E, x)
        x = minimise(E, x, free_released)
    assert E.min_jacobian(x) > 0
    g = E.gradient(x)
    assert np.linalg.norm(g[free_released]) < 1e-6 * np.linalg.norm(E.gradient(X * [1.6, 1, 1]))
    length = x[right, 0].mean()
    if plastic:
        # permanent deformation: the bar stays much longer than its original length
        assert length > 1.3 * L
        assert P is not None and P.plastic_strain is not None
        assert np.all(P.plastic_strain > 0)
        assert E.value(x) < 0.05 * E.volumes.sum() * E.mu[0]  # mostly relaxed: what is left is residual stress
    else:
        np.testing.assert_allclose(x, X, atol=1e-8)
        assert E.value(x) < 1e-12
