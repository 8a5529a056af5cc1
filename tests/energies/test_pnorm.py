"""Tests of the p-norm distortion energy (paper §7.4, eq. 9): finite differences of value, gradient and exact
Hessian for p = 1, 2, 5, 10 in 2D and 3D over symmetric Dirichlet and neo-Hookean; the PSD projection; the
rest-shape calibration r(p); the compiled kernel against the numpy reference; finite values for strongly
distorted starts (the overflow-free continuation); bad parameters."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.sparse as sp

from idp.energies import _elastic_kernels as K
from idp.energies import _pnorm_kernels as PK
from idp.energies.elastic import ElasticEnergy
from idp.energies.pnorm import PNormEnergy

POWERS = [1.0, 2.0, 5.0, 10.0]
MODELS = ["symmetric_dirichlet", "neo_hookean"]
DIMS = [2, 3]


def _simplices(d: int, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` separate, positively oriented, randomly shaped simplices."""
    rng = np.random.default_rng(seed)
    X = np.vstack(
        [np.vstack([np.zeros(d), np.eye(d)]) + 0.2 * rng.normal(size=(d + 1, d)) + 4.0 * i for i in range(count)]
    )
    T = np.arange(count * (d + 1)).reshape(count, d + 1)
    Dm = np.transpose(X[T[:, 1:]] - X[T[:, :1]], (0, 2, 1))
    neg = np.linalg.det(Dm) < 0
    T[neg, 0], T[neg, 1] = T[neg, 1].copy(), T[neg, 0].copy()
    return X, T


def _deformed(X: np.ndarray, T: np.ndarray, amount: float, seed: int) -> np.ndarray:
    """A positively oriented deformation: per-simplex random linear maps with singular values in [1/(1+a), 1+a]."""
    rng = np.random.default_rng(seed)
    d = X.shape[1]
    Y = X.copy()
    for t in T:
        q1, _ = np.linalg.qr(rng.normal(size=(d, d)))
        q2, _ = np.linalg.qr(rng.normal(size=(d, d)))
        s = np.exp(rng.uniform(-1.0, 1.0, d) * math.log1p(amount))
        A = q1 @ np.diag(s) @ q2.T
        if np.linalg.det(A) < 0:
            A = A @ np.diag([-1.0] + [1.0] * (d - 1))
        c = X[t].mean(axis=0)
        Y[t] = c + (X[t] - c) @ A.T
    return Y


def _energy(model: str, X: np.ndarray, T: np.ndarray, p: float) -> PNormEnergy:
    return PNormEnergy(model, X, T, 1e4, 0.3, power=p)


def _assemble(E: ElasticEnergy, H: np.ndarray) -> sp.csr_matrix:
    dofs = E.element_dofs()
    k = dofs.shape[1]
    n = E.num_vertices * E.dim
    return sp.coo_matrix(
        (H.ravel(), (np.repeat(dofs, k, axis=1).ravel(), np.tile(dofs, (1, k)).ravel())), shape=(n, n)
    ).tocsr()


CASES = list(itertools.product(MODELS, DIMS, POWERS))


@pytest.mark.parametrize("model,d,p", CASES)
def test_gradient_and_exact_hessian_match_finite_differences(model: str, d: int, p: float) -> None:
    X, T = _simplices(d, 3, seed=d)
    E = _energy(model, X, T, p)
    x = _deformed(X, T, 0.8, seed=10 + d).ravel()
    f0 = E.value(x)
    assert np.isfinite(f0) and f0 > 0
    g = E.gradient(x)
    h = 1e-6 * np.abs(x).max()
    fd = np.array([(E.value(x + h * e) - E.value(x - h * e)) / (2 * h) for e in np.eye(x.size)])
    # central differences: truncation ~h² E''' and rounding ~eps f/h, both far below 1e-6 ‖g‖ here
    assert np.linalg.norm(fd - g) <= 1e-6 * np.linalg.norm(g), (model, d, p)
    Hm = _assemble(E, E.element_hessians(x, project=False))
    rng = np.random.default_rng(3)
    for _ in range(3):
        v = rng.normal(size=x.size)
        fdv = (E.gradient(x + h * v) - E.gradient(x - h * v)) / (2 * h)
        assert np.linalg.norm(fdv - Hm @ v) <= 1e-5 * np.linalg.norm(Hm @ v), (model, d, p)


@pytest.mark.parametrize("model,d,p", CASES)
def test_kernel_matches_numpy_reference(model: str, d: int, p: float) -> None:
    X, T = _simplices(d, 4, seed=20 + d)
    E = _energy(model, X, T, p)
    x = _deformed(X, T, 1.5, seed=30 + d)
    m, k = len(T), (d + 1) * d
    for project in (True, False):
        e, g, H = np.empty(m), np.empty((m, k)), np.empty((m, k, k))
        K.element_terms(x, E.elements, E.Dm_inv, E.volumes, E._model_id, E._pa, E._pb, True, True, project, p, e, g, H)
        er, gr, Hr = K.element_terms_reference(
            x, E.elements, E.Dm_inv, E.volumes, E._model_id, E._pa, E._pb, project, power=p
        )
        # two routes (closed forms vs LAPACK SVD/eigh and dF/dx): agreement to rounding of the larger terms
        np.testing.assert_allclose(e, er, rtol=1e-11)
        assert np.all(np.abs(g - gr) <= 1e-10 * np.abs(gr).max(axis=1)[:, None])
        assert np.all(np.abs(H - Hr) <= 1e-10 * np.abs(Hr).max(axis=(1, 2))[:, None, None])


@pytest.mark.parametrize("model,d,p", CASES)
def test_projected_hessian_is_psd_and_dominates_the_exact_one(model: str, d: int, p: float) -> None:
    """The projection clamps negative eigenvalues of the Hessian in F-space: H₊ ⪰ 0 and H₊ − H ⪰ 0; where the
    exact Hessian is already PSD (mild deformations) both are the same."""
    X, T = _simplices(d, 6, seed=40 + d)
    E = _energy(model, X, T, p)
    for amount, seed in ((0.05, 1), (2.0, 2), (4.0, 3)):
        x = _deformed(X, T, amount, seed=seed)
        Hp = E.element_hessians(x, project=True)
        He = E.element_hessians(x, project=False)
        scale = np.abs(He).max(axis=(1, 2))
        assert np.all(np.linalg.eigvalsh(Hp).min(axis=1) >= -1e-10 * scale)
        assert np.all(np.linalg.eigvalsh(Hp - He).min(axis=1) >= -1e-10 * scale)
        psd = np.linalg.eigvalsh(He).min(axis=1) >= 1e-9 * scale
        np.testing.assert_allclose(Hp[psd], He[psd], rtol=0, atol=1e-10 * scale.max())


@pytest.mark.parametrize("model,d,p", CASES)
def test_rest_calibration_keeps_stress_and_its_derivative(model: str, d: int, p: float) -> None:
    """r(p) makes E_p and the base energy agree to second order at the rest shape (eq. 9): both gradients
    vanish at a rigid motion of the rest shape, their Hessians there are equal, and near rest the gradients
    differ only at second order in the distance from rest."""
    X, T = _simplices(d, 3, seed=50 + d)
    Ep = _energy(model, X, T, p)
    Eb = ElasticEnergy(model, X, T, 1e4, 0.3)
    q, _ = np.linalg.qr(np.random.default_rng(5).normal(size=(d, d)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    rigid = X @ q.T + 0.3
    gscale = np.abs(Eb.gradient(_deformed(X, T, 0.1, seed=6))).max()
    assert np.abs(Ep.gradient(rigid)).max() <= 1e-9 * gscale
    assert np.abs(Eb.gradient(rigid)).max() <= 1e-9 * gscale
    Hp, Hb = Ep.element_hessians(rigid, project=False), Eb.element_hessians(rigid, project=False)
    np.testing.assert_allclose(Hp, Hb, rtol=0, atol=1e-9 * np.abs(Hb).max())
    diffs = []
    for eps in (1e-2, 1e-3):
        x = X + eps * (_deformed(X, T, 1.0, seed=7) - X)
        gb = Eb.gradient(x)
        diffs.append(np.linalg.norm(Ep.gradient(x) - gb) / np.linalg.norm(gb))
    if p == 1.0:
        assert max(diffs) <= 1e-12
    else:
        # relative difference O(eps): shrinks ~10× when eps does
        assert diffs[1] <= 0.2 * diffs[0]


def test_value_is_the_formula_of_eq_9() -> None:
    """E_p = Ψ̂(I)^{1−p}/p Σ v (Ψ̂)^p with Ψ̂ = w(‖F‖² + ‖F⁻¹‖²) for SD, computed here from F directly (p > 1)."""
    X, T = _simplices(2, 5, seed=60)
    x = _deformed(X, T, 1.2, seed=61)
    for p in POWERS:
        E = _energy("symmetric_dirichlet", X, T, p)
        F = E.deformation_gradients(x)
        psi_hat = E.weight * (np.einsum("mij,mij->m", F, F) + np.einsum("mij,mij->m", *(2 * [np.linalg.inv(F)])))
        psi_I = 4.0 * E.weight
        expected = np.sum(E.volumes * psi_I ** (1 - p) / p * psi_hat**p)
        if p == 1.0:  # p = 1 is the base energy, whose Ψ = Ψ̂ − Ψ̂(I) is zero at rest
            expected -= np.sum(E.volumes * psi_I)
        assert E.value(x) == pytest.approx(expected, rel=1e-12)
        np.testing.assert_allclose(E.rest_distortion(), psi_I)


def test_large_p_on_a_nearly_collapsed_element_stays_finite() -> None:
    """ρ = 1e40 at p = 10: ρ^p = 1e400 overflows a double; the continuation keeps everything finite and still
    growing with the distortion, and the exact branch and the continuation meet with matching derivatives."""
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.3, 1.0]])
    T = np.array([[0, 1, 2]])
    E = _energy("symmetric_dirichlet", X, T, 10.0)
    x = X.copy()
    x[2, 1] = 1e-20  # height squashed by 1e-20: ‖F⁻¹‖² ~ 1e40
    f, g, H = E.value_gradient_hessian(x, project=True)
    assert np.isfinite(f) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))
    x2 = x.copy()
    x2[2, 1] = 0.5e-20
    assert E.value(x2) > f  # more collapsed, more energy
    p = 10.0
    rc = math.exp(PK.LOG_CAP / p)
    below = PK.power_tail(rc * (1 - 1e-12), p)
    above = PK.power_tail(rc * (1 + 1e-12), p)
    for a, b in zip(below, above, strict=True):
        assert a == pytest.approx(b, rel=1e-9)
    assert E.exact_ratio_limit == pytest.approx(rc)


def test_p_one_is_the_base_energy_up_to_a_constant() -> None:
    X, T = _simplices(3, 3, seed=80)
    x = _deformed(X, T, 0.7, seed=81)
    for model in MODELS:
        E1 = _energy(model, X, T, 1.0)
        Eb = ElasticEnergy(model, X, T, 1e4, 0.3)
        assert E1.value(x) == pytest.approx(Eb.value(x), rel=1e-14)  # power 1 runs the base kernel path
        np.testing.assert_array_equal(E1.gradient(x), Eb.gradient(x))  # same code path, same arithmetic


def test_model_constants_agree_with_the_element_kernel() -> None:
    assert PK.NEO_HOOKEAN == K.NEO_HOOKEAN and PK.SYMMETRIC_DIRICHLET == K.SYMMETRIC_DIRICHLET


def test_bad_parameters_are_refused() -> None:
    X, T = _simplices(2, 1, seed=90)
    with pytest.raises(ValueError, match=">= 1"):
        PNormEnergy("symmetric_dirichlet", X, T, 1e4, 0.3, power=0.5)
    with pytest.raises(ValueError, match=">= 1"):
        PNormEnergy("symmetric_dirichlet", X, T, 1e4, 0.3, power=float("nan"))
    with pytest.raises(ValueError, match="extends"):
        PNormEnergy("arap", X, T, 1e4, 0.3, power=2.0)
    with pytest.raises(ValueError, match="poisson_ratio >= 0"):
        PNormEnergy("neo_hookean", X, T, 1e4, -0.2, power=2.0)
