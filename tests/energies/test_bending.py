"""Tests of idp.energies.bending and idp.mesh.hinges: hinge extraction (count, orientation, non-manifold
error), the signed dihedral angle (flat, prescribed folds up to ±(π - 0.05), convex tetrahedron), the
energy formula, central-difference checks of the analytic gradient and Hessian on random, nearly flat
and sharply folded hinges, zero energy / gradient at rest, rigid-motion invariance and PSD projection.

Tolerances: central differences with ε = 1e-6 on O(1) coordinates have truncation ~ε²|f'''| and
round-off ~u|f|/ε, both ≲ 1e-9 relative; 1e-6 (gradient) and 1e-5 (Hessian) are safe yet catch any
wrong term.  Near a fold of π - 0.05 the third derivatives grow like 1/h², still ≪ 1/ε²."""

from __future__ import annotations

import numpy as np
import pytest
from finite_differences import fd_gradient, fd_hessian

from idp.energies.bending import BendingEnergy, bending_stiffness, dihedral_angles
from idp.energies.term import ElementTerm
from idp.mesh.generate import tri_rectangle
from idp.mesh.hinges import triangle_hinges


def _hinge(phi: float) -> np.ndarray:
    """Edge x0=(0,0,0)–x1=(1,0,0), x2 in the plane z = 0, x3 rotated by phi about the edge (θ = phi)."""
    return np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [0.6, -np.cos(phi), -np.sin(phi)]])


def _sheet(res: int = 3) -> tuple[np.ndarray, np.ndarray]:
    m = tri_rectangle((0.0, 0.0), (1.0, 1.0), (res, res))
    X = np.zeros((m.vertices.shape[0], 3))
    X[:, :2] = m.vertices
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


# ------------------------------------------------------------------ hinges


def test_hinges_of_a_grid_are_the_interior_edges_and_follow_the_winding() -> None:
    X, T = _sheet(2)  # 9 vertices, 8 triangles, 16 edges of which 8 interior
    H, F = triangle_hinges(T, return_faces=True)
    assert H.shape == (8, 4) and F.shape == (8, 2)
    for (x0, x1, x2, x3), (f1, f2) in zip(H, F, strict=True):
        t1, t2 = T[f1].tolist(), T[f2].tolist()
        k = t1.index(x0)
        assert t1[(k + 1) % 3] == x1 and t1[(k + 2) % 3] == x2  # face 1 = (x0, x1, x2) in winding order
        k = t2.index(x1)
        assert t2[(k + 1) % 3] == x0 and t2[(k + 2) % 3] == x3  # consistent mesh: face 2 = (x1, x0, x3)
    np.testing.assert_allclose(dihedral_angles(X, H), 0.0, atol=1e-15)


def test_non_manifold_edge_is_named() -> None:
    T = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(ValueError, match=r"edge \(0, 1\) has 3 faces"):
        triangle_hinges(T)
    assert triangle_hinges(np.array([[0, 1, 2]])).shape == (0, 4)


# ------------------------------------------------------------------ angle and energy


@pytest.mark.parametrize("phi", [0.0, 1e-7, -1e-4, 0.5, -1.2, 2.5, np.pi - 0.05, -(np.pi - 0.05)])
def test_signed_angle_of_a_prescribed_fold(phi: float) -> None:
    theta = dihedral_angles(_hinge(phi), np.array([[0, 1, 2, 3]]))[0]
    assert theta == pytest.approx(phi, abs=1e-14)


def test_convex_closed_surface_has_positive_angles() -> None:
    # regular tetrahedron, outward winding: every exterior dihedral angle is π - arccos(1/3)
    X = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
    T = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    H = triangle_hinges(T)
    assert H.shape == (6, 4)
    np.testing.assert_allclose(dihedral_angles(X, H), np.pi - np.arccos(1.0 / 3.0), rtol=1e-14)


def test_energy_formula_and_stiffness() -> None:
    Y, nu, t, mult = 3.0e3, 0.3, 0.05, 2.0
    kb = bending_stiffness(Y, nu, t, mult)
    assert kb == pytest.approx(Y * t**3 / (24 * (1 - nu**2)) * mult)
    E = BendingEnergy(_hinge(0.0), [[0, 1, 2, 3]], Y, nu, t, mult)
    # |ē| = 1, Ā1 = Ā2 = ½ -> weight 3|ē|²/(Ā1+Ā2) = 3
    assert E.weights[0] == pytest.approx(3.0)
    assert E.value(_hinge(0.7)) == pytest.approx(kb * 3.0 * 0.7**2, rel=1e-13)
    E.set_rest_angles(0.2)
    assert E.value(_hinge(0.7)) == pytest.approx(kb * 3.0 * 0.5**2, rel=1e-12)
    assert E.value(_hinge(0.2)) == pytest.approx(0.0, abs=1e-20)


# ------------------------------------------------------------------ derivatives


def _cases() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """name -> (rest, hinges, current)."""
    rng = np.random.default_rng(4)
    X, T = _sheet(2)
    X[:, 2] = 0.1 * rng.normal(size=len(X))
    H = triangle_hinges(T)
    single = np.array([[0, 1, 2, 3]])
    return {
        "random_sheet": (X, H, X + 0.2 * rng.normal(size=X.shape)),
        "nearly_flat": (_hinge(0.3), single, _hinge(1e-5) + 1e-7 * rng.normal(size=(4, 3))),
        "sharp_fold": (_hinge(0.1), single, _hinge(np.pi - 0.05) + 1e-3 * rng.normal(size=(4, 3))),
        "sharp_fold_negative": (_hinge(-0.4), single, _hinge(-(np.pi - 0.05))),
        "random_hinge": (_hinge(0.2), single, _hinge(0.2) + 0.3 * rng.normal(size=(4, 3))),
    }


@pytest.mark.parametrize("name", list(_cases()))
def test_gradient_and_hessian_match_finite_differences(name: str) -> None:
    X, H, x = _cases()[name]
    E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
    g = E.gradient(x)
    gf = fd_gradient(E.value, x)
    assert np.linalg.norm(g - gf) <= 1e-6 * np.linalg.norm(g)
    Hx = _assemble(E, E.element_hessians(x, project=False), len(X))
    Hf = fd_hessian(E.gradient, x)
    assert np.abs(Hx - Hx.T).max() <= 1e-12 * np.abs(Hx).max()
    assert np.linalg.norm(Hx - Hf) <= 1e-5 * np.linalg.norm(Hx)


def test_rest_state_and_rigid_motions() -> None:
    rng = np.random.default_rng(9)
    X, H, x = _cases()["random_sheet"]
    E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
    assert E.value(X) == pytest.approx(0.0, abs=1e-20)
    assert np.abs(E.gradient(X)).max() <= 1e-12
    v = E.value(x)
    g = E.gradient(x).reshape(-1, 3)
    for _ in range(3):
        R, t = _rotation(rng), rng.normal(size=3)
        assert E.value(x @ R.T + t) == pytest.approx(v, rel=1e-11)
        np.testing.assert_allclose(E.gradient(x @ R.T + t).reshape(-1, 3), g @ R.T, atol=1e-9 * np.abs(g).max())
        assert E.value(X @ R.T + t) == pytest.approx(0.0, abs=1e-18)
    # a rigid motion of the rest shape itself leaves the rest angles and weights unchanged
    E2 = BendingEnergy(X @ R.T + t, H, 1.0e3, 0.3, 0.1)
    np.testing.assert_allclose(E2.rest_angles, E.rest_angles, atol=1e-13)
    np.testing.assert_allclose(E2.weights, E.weights, rtol=1e-12)


def test_projected_blocks_are_psd_and_exact_where_psd() -> None:
    seen_exact = seen_projected = 0
    for name, (X, H, x) in _cases().items():
        E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
        for y in (x, X):  # at rest the exact block 2c∇θ∇θᵀ is PSD (rank 1)
            Hx = E.element_hessians(y, project=False)
            Hp = E.element_hessians(y, project=True)
            for a, b in zip(Hx, Hp, strict=True):
                scale = max(np.abs(a).max(), 1e-300)
                assert np.linalg.eigvalsh(b).min() >= -1e-12 * scale, name
                if np.linalg.eigvalsh(a).min() >= -1e-12 * scale:
                    np.testing.assert_allclose(b, a, atol=1e-12 * scale)
                    seen_exact += 1
                else:
                    seen_projected += 1
    assert seen_exact > 0 and seen_projected > 0


@pytest.mark.parametrize("name", list(_cases()))
def test_gauss_newton_blocks_are_the_rank_one_part(name: str) -> None:
    """``hessian = "gauss_newton"``: each PSD block is 2c∇θ∇θᵀ (its quadratic form 2c(∇θ·v)², ∇θ·v by central
    differences of the angle), the exact one where δ = 0 (at rest); an exact request stays exact."""
    X, H, x = _cases()[name]
    E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1, hessian="gauss_newton")
    P = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
    np.testing.assert_array_equal(E.element_hessians(x, project=False), P.element_hessians(x, project=False))
    blocks = E.element_hessians(x, project=True)
    c = E._stiffness
    rng = np.random.default_rng(3)
    eps = 1e-6
    for k, (dofs, b) in enumerate(zip(E.element_dofs(), blocks, strict=True)):
        scale = max(np.abs(b).max(), 1e-300)
        w = np.linalg.eigvalsh(b)
        assert w.min() >= -1e-12 * scale and np.sum(w > 1e-9 * scale) <= 1
        for _ in range(3):
            v = rng.normal(size=12)
            dv = np.zeros(x.size)
            dv[dofs] = v
            angle = lambda y: dihedral_angles(y.reshape(-1, 3), H[k : k + 1])[0]  # noqa: E731
            slope = (angle(x.ravel() + eps * dv) - angle(x.ravel() - eps * dv)) / (2 * eps)
            assert v @ b @ v == pytest.approx(2 * c[k] * slope**2, rel=1e-6, abs=1e-9 * scale)
    at_rest = E.element_hessians(X, project=True)
    np.testing.assert_allclose(at_rest, P.element_hessians(X, project=False), atol=1e-12 * np.abs(at_rest).max())


def test_unknown_bending_hessian_is_refused() -> None:
    X, H, _ = _cases()["random_sheet"]
    with pytest.raises(ValueError, match="bending hessian"):
        BendingEnergy(X, H, 1.0e3, 0.3, 0.1, hessian="exact")


def test_set_rest_shape_and_protocol() -> None:
    rng = np.random.default_rng(1)
    X, H, x = _cases()["random_sheet"]
    E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
    assert isinstance(E, ElementTerm)
    assert E.element_dofs().shape == (len(H), 12)
    E.set_rest_shape(x)
    assert E.value(x) == pytest.approx(0.0, abs=1e-20)
    np.testing.assert_allclose(E.rest_angles, E.angles(x), atol=1e-15)
    y = x + 0.05 * rng.normal(size=x.shape)
    got = []
    val, grad = E.value_gradient_hessian_groups(y, lambda first, b: got.append(b.copy()), group=3)
    np.testing.assert_allclose(np.concatenate(got), E.element_hessians(y), rtol=1e-13, atol=1e-13)
    assert val == pytest.approx(E.value(y), rel=1e-13)
    np.testing.assert_allclose(grad, E.gradient(y), rtol=1e-13, atol=1e-15)
    bad = X.copy()
    bad[H[0, 1]] = bad[H[0, 0]]
    with pytest.raises(ValueError, match="hinge 0"):
        E.set_rest_shape(bad)
    E2 = BendingEnergy.from_triangles(X, _sheet(2)[1], 1.0e3, 0.3, 0.1)
    np.testing.assert_array_equal(E2.hinges, H)


def test_skipped_stencils_contribute_nothing_and_the_others_are_unchanged() -> None:
    """``value_gradient_hessian_groups(skip=…)``: a long run of skipped hinges is not evaluated (no energy, gradient
    or block); short skipped gaps may be evaluated with their neighbours; every kept hinge is evaluated, and every
    evaluated block and the gradient are those of the full evaluation (small groups, so runs cross group borders)."""
    from idp.energies._stencil_term import MIN_SKIPPED_RUN

    X, F = _sheet(30)
    H = triangle_hinges(F)
    rng = np.random.default_rng(3)
    x = X + 0.02 * rng.standard_normal(X.shape)
    E = BendingEnergy(X, H, 1.0e3, 0.3, 0.1)
    m = len(H)
    assert m > 3 * MIN_SKIPPED_RUN
    skip = rng.random(m) < 0.3  # short gaps
    long_run = slice(m // 3, m // 3 + 2 * MIN_SKIPPED_RUN)
    skip[long_run] = True
    full: dict[int, np.ndarray] = {}
    part: dict[int, np.ndarray] = {}

    def collect(into):
        def sink(first, blocks):
            for j in range(blocks.shape[0]):
                into[first + j] = blocks[j].copy()

        return sink

    _, g_full = E.value_gradient_hessian_groups(x, collect(full), group=64)
    e_part, g_part = E.value_gradient_hessian_groups(x, collect(part), group=64, skip=skip)
    done = np.zeros(m, dtype=bool)
    done[list(part)] = True
    assert done[~skip].all() and not done[long_run].any()
    for i in part:
        np.testing.assert_array_equal(part[i], full[i])
    energies, grads = E.element_energies(x), E._run(x, True, False, False)[1]
    assert e_part == pytest.approx(energies[done].sum(), rel=1e-12)
    g_left_out = np.zeros_like(g_full)
    np.add.at(g_left_out, E.element_dofs()[~done].ravel(), grads[~done].ravel())
    np.testing.assert_allclose(g_part, g_full - g_left_out, rtol=0, atol=1e-12 * np.abs(g_full).max())
