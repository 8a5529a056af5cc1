"""Tests of idp.energies.membrane (StVK membrane on 3D triangles): central-difference checks of the
gradient and exact Hessian on random, stretched, compressed and nearly collapsed configurations, zero
energy / gradient at rest and under rigid motions, PSD projection, the closed form under uniaxial
stretch (which pins the plane-stress λ), the rest-shape update and the ElementTerm plumbing.

Finite-difference tolerances: central differences with step ε have truncation error ~ε²|f'''| and
round-off ~u|f|/ε (u = 2.2e-16).  With ε = 1e-6 (coordinates O(1)) both are ≲ 1e-9 relative to the
derivative's scale, so 1e-6 (gradient) and 1e-5 (Hessian, a difference of computed gradients) leave
ample margin while still catching any wrong term (those are O(1) relative)."""

from __future__ import annotations

import numpy as np
import pytest
from finite_differences import fd_gradient, fd_hessian

from idp.energies.membrane import MembraneEnergy, membrane_lame
from idp.energies.term import ElementTerm
from idp.mesh.generate import tri_rectangle


def _sheet(res: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A gently curved (non-planar) sheet of triangles in 3D."""
    m = tri_rectangle((0.0, 0.0), (1.0, 0.8), (res, res))
    X = np.zeros((m.vertices.shape[0], 3))
    X[:, :2] = m.vertices
    X[:, 2] = 0.2 * np.sin(2.0 * X[:, 0]) * np.cos(1.5 * X[:, 1])
    return X, m.elements


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _assemble(term, blocks: np.ndarray, n: int) -> np.ndarray:
    H = np.zeros((3 * n, 3 * n))
    for dofs, b in zip(term.element_dofs(), blocks, strict=True):
        H[np.ix_(dofs, dofs)] += b
    return H


def _configurations(X: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    c = X.mean(axis=0)
    collapsed = X.copy()
    collapsed[:, 1] = c[1] + 1e-4 * (X[:, 1] - c[1])  # nearly collapsed triangles (degenerate-near)
    return {
        "random": X + 0.15 * rng.normal(size=X.shape),
        "stretched": c + (X - c) * np.array([1.8, 1.3, 1.0]) + 0.01 * rng.normal(size=X.shape),
        "compressed": c + (X - c) * np.array([0.4, 0.7, 1.0]) + 0.01 * rng.normal(size=X.shape),
        "nearly_collapsed": collapsed,
    }


@pytest.mark.parametrize("name", ["random", "stretched", "compressed", "nearly_collapsed"])
def test_gradient_and_hessian_match_finite_differences(name: str) -> None:
    rng = np.random.default_rng(7)
    X, T = _sheet(2)
    E = MembraneEnergy(X, T, youngs_modulus=rng.uniform(1.0, 3.0, len(T)), poisson_ratio=0.3, thickness=0.1)
    x = _configurations(X, rng)[name]
    g = E.gradient(x)
    gf = fd_gradient(E.value, x)
    assert np.linalg.norm(g - gf) <= 1e-6 * max(float(np.linalg.norm(g)), 1e-8)
    H = _assemble(E, E.element_hessians(x, project=False), X.shape[0])
    Hf = fd_hessian(E.gradient, x)
    assert np.abs(H - H.T).max() <= 1e-12 * np.abs(H).max()
    assert np.linalg.norm(H - Hf) <= 1e-5 * np.linalg.norm(H)


def test_rest_state_and_rigid_motions_cost_nothing() -> None:
    rng = np.random.default_rng(3)
    X, T = _sheet(3)
    E = MembraneEnergy(X, T, 1e4, 0.4, 0.01)
    assert E.value(X) == pytest.approx(0.0, abs=1e-18)
    assert np.abs(E.gradient(X)).max() <= 1e-12
    scale = 1e4 * 0.01 * E.rest_areas.sum()  # energy scale of an O(1) strain
    for _ in range(3):
        x = X @ _rotation(rng).T + rng.normal(size=3)
        assert abs(E.value(x)) <= 1e-12 * scale
        assert np.abs(E.gradient(x)).max() <= 1e-10 * scale


def test_uniaxial_stretch_closed_form_and_plane_stress_lambda() -> None:
    # one right triangle in the xy-plane stretched by s along x: E = diag((s²-1)/2, 0) in an orthonormal rest frame
    Y, nu, t, s = 2.0e3, 0.35, 0.02, 1.3
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    E = MembraneEnergy(X, [[0, 1, 2]], Y, nu, t)
    mu, lam = membrane_lame(Y, nu)
    assert lam == pytest.approx(Y * nu / (1 - nu**2))
    e = 0.5 * (s * s - 1.0)
    expected = 0.5 * t * (mu * e * e + 0.5 * lam * e * e)
    x = X * np.array([s, 1.0, 1.0])
    assert E.value(x) == pytest.approx(expected, rel=1e-12)
    # the same after an arbitrary rigid motion of the rest shape (the metric form is frame-free)
    R = _rotation(np.random.default_rng(0))
    E2 = MembraneEnergy(X @ R.T, [[0, 1, 2]], Y, nu, t)
    assert E2.value(x @ R.T + 3.0) == pytest.approx(expected, rel=1e-10)
    strain = E.green_strains(x)[0]
    np.testing.assert_allclose(strain, [[e, 0.0], [0.0, 0.0]], atol=1e-14)


def test_projected_blocks_are_psd_and_exact_where_psd() -> None:
    rng = np.random.default_rng(11)
    X, T = _sheet(3)
    E = MembraneEnergy(X, T, 1.0, 0.3, 1.0)
    exact_psd_seen = projected_seen = 0
    for name, x in _configurations(X, rng).items():
        Hx = E.element_hessians(x, project=False)
        Hp = E.element_hessians(x, project=True)
        for a, b in zip(Hx, Hp, strict=True):
            scale = np.abs(a).max()
            assert np.linalg.eigvalsh(b).min() >= -1e-12 * scale, name
            if np.linalg.eigvalsh(a).min() >= -1e-12 * scale:
                np.testing.assert_allclose(b, a, atol=1e-12 * scale)
                exact_psd_seen += 1
            else:
                projected_seen += 1
    assert exact_psd_seen > 0 and projected_seen > 0  # compression makes StVK indefinite


def test_set_rest_shape_and_material() -> None:
    rng = np.random.default_rng(5)
    X, T = _sheet(2)
    E = MembraneEnergy(X, T, 1.0, 0.3, 0.1)
    X2 = X * 1.5 + 0.01 * rng.normal(size=X.shape)
    assert E.value(X2) > 0
    E.set_rest_shape(X2)
    assert E.value(X2) == pytest.approx(0.0, abs=1e-18)
    assert np.abs(E.gradient(X2)).max() <= 1e-12
    x = X2 + 0.1 * rng.normal(size=X.shape)
    v = E.value(x)
    E.set_material(2.0, 0.3, 0.1)
    assert E.value(x) == pytest.approx(2.0 * v, rel=1e-12)
    bad = X.copy()
    bad[T[0, 1]] = bad[T[0, 0]]
    with pytest.raises(ValueError, match="triangle 0"):
        E.set_rest_shape(bad)
    with pytest.raises(ValueError, match="poisson_ratio"):
        MembraneEnergy(X, T, 1.0, 0.6, 0.1)


def test_element_term_protocol_and_grouped_hessians() -> None:
    rng = np.random.default_rng(2)
    X, T = _sheet(3)
    E = MembraneEnergy(X, T, 1.0, 0.3, 0.1)
    assert isinstance(E, ElementTerm)
    assert E.element_dofs().shape == (len(T), 9)
    x = X + 0.1 * rng.normal(size=X.shape)
    got: dict[int, np.ndarray] = {}
    val, grad = E.value_gradient_hessian_groups(x, lambda first, blocks: got.__setitem__(first, blocks.copy()), group=5)
    assert sorted(got) == list(range(0, len(T), 5))
    np.testing.assert_allclose(np.concatenate([got[k] for k in sorted(got)]), E.element_hessians(x), rtol=1e-13)
    assert val == pytest.approx(E.value(x), rel=1e-13)
    np.testing.assert_allclose(grad, E.gradient(x), rtol=1e-13, atol=1e-15)
