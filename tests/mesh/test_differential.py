"""Tests of idp.mesh.differential: area-weighted normals of a sphere point outward, lumped areas sum
to the surface area, the cotangent Laplacian is symmetric negative semidefinite with zero row sums and
annihilates linear functions at interior vertices of a flat mesh, the area ("umbrella") Laplacian has
non-negative weights (A_1+A_2)/3, and ``LaplacianSmoothing``'s assembled Hessian equals -γ L (⊗ I₃) for
either weighting, with value / gradient / Hessian matching finite differences; ``NormalForce`` is linear
and both of its weightings point outward on a sphere."""

from __future__ import annotations

import numpy as np
import pytest
from finite_differences import fd_gradient, fd_hessian

from idp.energies._stencil_term import scatter_gradient
from idp.energies.term import ElementTerm
from idp.mesh.differential import (
    LaplacianSmoothing,
    NormalForce,
    area_laplacian,
    area_weights,
    cotangent_laplacian,
    vertex_areas,
    vertex_normals,
)
from idp.mesh.generate import revolve_profile, tri_rectangle
from idp.mesh.surface import boundary_vertices
from idp.solver.assembly import FixedPatternAssembler, FreeDofMap


def _sphere(radius: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(-0.5 * np.pi, 0.5 * np.pi, 13)
    m = revolve_profile(radius * np.sin(t), radius * np.cos(t), 24)  # bottom to top: outward faces
    return m.vertices, m.faces


def _flat(res: int = 5, jitter: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    m = tri_rectangle((0.0, 0.0), (2.0, 1.0), (res, res))
    X = np.zeros((m.vertices.shape[0], 3))
    X[:, :2] = m.vertices
    inner = np.setdiff1d(np.arange(len(X)), boundary_vertices(_edges_boundary(m.elements)))
    X[inner, :2] += jitter * np.random.default_rng(seed).uniform(-1, 1, size=(inner.size, 2))
    return X, m.elements


def _edges_boundary(T: np.ndarray) -> np.ndarray:
    """Boundary edges (k,2) of a triangle mesh (edges with one face)."""
    e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def test_sphere_normals_point_outward_and_areas_sum_to_the_surface() -> None:
    X, T = _sphere()
    N = vertex_normals(X, T)
    U = vertex_normals(X, T, unit=True)
    radial = X / np.linalg.norm(X, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", U, radial) > 0.99)
    np.testing.assert_allclose(np.linalg.norm(U, axis=1), 1.0, rtol=1e-14)
    A = vertex_areas(X, T)
    face_area = 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1)
    assert A.sum() == pytest.approx(face_area.sum(), rel=1e-13)
    assert face_area.sum() == pytest.approx(4 * np.pi * 1.5**2, rel=2e-2)  # a fine polyhedral sphere
    # raw normals are 3x lumped-area weighted: |N_i| ≈ 3 A_i on a smooth surface
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 3 * A, rtol=0.05)
    # closed surface: Σ_t A_t n̂_t = 0
    assert np.abs(N.sum(axis=0)).max() <= 1e-12


@pytest.mark.parametrize("jitter", [0.0, 0.08])
def test_cotangent_laplacian_properties_on_a_flat_mesh(jitter: float) -> None:
    X, T = _flat(5, jitter)
    L = cotangent_laplacian(X, T)
    Ld = L.toarray()
    np.testing.assert_allclose(Ld, Ld.T, atol=1e-14)
    np.testing.assert_allclose(Ld.sum(axis=1), 0.0, atol=1e-13)
    assert np.linalg.eigvalsh(Ld).max() <= 1e-12
    inner = np.setdiff1d(np.arange(len(X)), boundary_vertices(_edges_boundary(T)))
    for f in (X[:, 0], X[:, 1], 0.3 * X[:, 0] - 1.7 * X[:, 1] + 2.0):
        assert np.abs((L @ f)[inner]).max() <= 1e-12
    # -fᵀ L f is the Dirichlet energy ∫|∇f|², exact for the piecewise-linear f = x on the 2 x 1 rectangle
    f = X[:, 0]
    assert -(f @ (L @ f)) == pytest.approx(2.0 * 1.0, rel=1e-12)  # ∫|∇f|² over the 2 x 1 rectangle


def _face_areas(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1)


@pytest.mark.parametrize("jitter", [0.0, 0.08])
def test_area_laplacian_properties(jitter: float) -> None:
    X, T = _flat(4, jitter)
    X[:, 2] = 0.1 * np.cos(2 * X[:, 1])
    w = area_weights(X, T)
    A = _face_areas(X, T)
    np.testing.assert_allclose(w, np.repeat(A[:, None] / 6.0, 3, axis=1), rtol=1e-14)
    Ld = area_laplacian(X, T).toarray()
    np.testing.assert_allclose(Ld, Ld.T, atol=1e-14)
    np.testing.assert_allclose(Ld.sum(axis=1), 0.0, atol=1e-13)
    assert np.all(Ld - np.diag(np.diag(Ld)) >= 0)  # non-negative edge weights
    assert np.linalg.eigvalsh(Ld).max() <= 1e-12
    # an interior edge gets (A_1 + A_2)/6, a boundary edge A_t/6
    e = np.sort(np.concatenate([T[:, [1, 2]], T[:, [2, 0]], T[:, [0, 1]]]), axis=1)
    face = np.tile(np.arange(len(T)), 3)
    u, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    expected = np.bincount(inv.ravel(), weights=A[face] / 6.0)
    np.testing.assert_allclose(Ld[u[:, 0], u[:, 1]], expected, rtol=1e-13)
    assert np.any(cnt == 1) and np.any(cnt == 2)


def _laplacian(weights: str, X: np.ndarray, T: np.ndarray):
    return cotangent_laplacian(X, T) if weights == "cotangent" else area_laplacian(X, T)


@pytest.mark.parametrize("weights", ["cotangent", "area"])
@pytest.mark.parametrize("jitter", [0.0, 0.12])
def test_laplacian_smoothing_hessian_is_minus_gamma_L(jitter: float, weights: str) -> None:
    rng = np.random.default_rng(2)
    X, T = _flat(4, jitter, seed=3)
    X[:, 2] = 0.05 * np.sin(3 * X[:, 0])
    gamma = 2.5
    S = LaplacianSmoothing(X, T, gamma, weights=weights)
    assert isinstance(S, ElementTerm)
    L = _laplacian(weights, X, T)
    np.testing.assert_allclose(S.laplacian().toarray(), L.toarray(), atol=1e-14)
    n = len(X)
    x = X + 0.1 * rng.normal(size=X.shape)
    blocks = S.element_hessians(x, project=False)
    for b in blocks:
        assert np.linalg.eigvalsh(b).min() >= -1e-13 * np.abs(b).max()
    np.testing.assert_allclose(S.element_hessians(x), blocks, atol=1e-13)  # projection: rounding only
    H = np.zeros((3 * n, 3 * n))
    for dofs, b in zip(S.element_dofs(), blocks, strict=True):
        H[np.ix_(dofs, dofs)] += b
    expected = -gamma * np.kron(L.toarray(), np.eye(3))
    np.testing.assert_allclose(H, expected, atol=1e-12 * np.abs(expected).max())
    # the project's assembler gives the same
    asm = FixedPatternAssembler([S.element_dofs()], FreeDofMap(np.ones(3 * n, dtype=bool)), dim=3)
    Ha = asm.assemble([blocks], [1.0], np.zeros(3 * n)).toarray()
    np.testing.assert_allclose(Ha, expected, atol=1e-12 * np.abs(expected).max())
    # value and gradient of the quadratic
    assert S.value(x) == pytest.approx(-0.5 * gamma * np.sum(x * (L @ x)), rel=1e-12)
    np.testing.assert_allclose(S.gradient(x), (-gamma * (L @ x)).ravel(), atol=1e-12)
    # translations cost nothing
    assert S.value(X + np.array([1.0, -2.0, 3.0])) == pytest.approx(S.value(X), rel=1e-12)


@pytest.mark.parametrize("weights", ["cotangent", "area"])
def test_laplacian_smoothing_matches_finite_differences(weights: str) -> None:
    rng = np.random.default_rng(5)
    X, T = _flat(2, 0.1, seed=1)
    X[:, 2] = 0.2 * np.sin(2 * X[:, 0])
    S = LaplacianSmoothing(X, T, 1.7, weights=weights)
    x = X + 0.2 * rng.normal(size=X.shape)
    g = S.gradient(x)
    gf = fd_gradient(S.value, x)
    assert np.linalg.norm(g - gf) <= 1e-7 * np.linalg.norm(g)
    H = np.zeros((x.size, x.size))
    for dofs, b in zip(S.element_dofs(), S.element_hessians(x, project=False), strict=True):
        H[np.ix_(dofs, dofs)] += b
    Hf = fd_hessian(S.gradient, x)
    assert np.linalg.norm(H - Hf) <= 1e-7 * np.linalg.norm(H)
    # the weights come from the construction shape and are not updated by moving x
    np.testing.assert_allclose(S.element_hessians(2.0 * x, project=False), S.element_hessians(x, project=False))


def _grouped(S: LaplacianSmoothing, x: np.ndarray, project: bool, skip=None) -> tuple[float, np.ndarray, np.ndarray]:
    """(energy, gradient, all blocks) from ``value_gradient_hessian_groups`` in groups of 7 stencils."""
    got = np.full((S.num_stencils, 9, 9), np.nan)

    def sink(first: int, blocks: np.ndarray) -> None:
        got[first : first + blocks.shape[0]] = blocks

    e, g = S.value_gradient_hessian_groups(x, sink, project=project, group=7, skip=skip)
    return e, g, got


@pytest.mark.parametrize("weights", ["cotangent", "area"])
def test_laplacian_smoothing_grouped_path_equals_the_stencil_sums(weights: str) -> None:
    """The sparse energy/gradient and the cached blocks equal the per-triangle evaluation, also after the weights
    and γ change (the cache follows them) and with skipped stencils (the stencil-wise path)."""
    rng = np.random.default_rng(8)
    X, T = _flat(4, 0.15, seed=2)
    X[:, 2] = 0.1 * np.cos(2 * X[:, 1])
    S = LaplacianSmoothing(X, T, 0.8, weights=weights)
    x = X + 0.05 * rng.normal(size=X.shape)
    for step in range(3):
        for project in (True, False):
            e, g, blocks = _grouped(S, x, project)
            per_triangle = S.element_energies(x)
            assert e == pytest.approx(per_triangle.sum(), rel=1e-12)
            assert S.value(x) == pytest.approx(per_triangle.sum(), rel=1e-12)
            stencil_grad = scatter_gradient(S.element_dofs(), S._run(x, True, False, False)[1], x.size)
            np.testing.assert_allclose(g, stencil_grad, atol=1e-13 * np.abs(stencil_grad).max())
            np.testing.assert_array_equal(blocks, S.element_hessians(x, project=project))
        if step == 0:
            S.set_weights(x)  # new weights: new blocks
        else:
            S.gamma = 2.0  # new γ: new blocks
        x = x + 0.05 * rng.normal(size=X.shape)
    skip = np.zeros(S.num_stencils, dtype=bool)
    skip[:5] = True
    e, g, blocks = _grouped(S, x, True, skip)
    assert e == pytest.approx(S.element_energies(x)[5:].sum(), rel=1e-12)
    assert np.isnan(blocks[:5]).all() and not np.isnan(blocks[5:]).any()


def test_area_weights_are_the_initial_areas_and_give_psd_blocks() -> None:
    X = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, -1.0, 0.0]])  # obtuse at vertex 2
    T = np.array([[0, 1, 2], [1, 0, 3]])
    S = LaplacianSmoothing(X, T, 1.0, weights="area")
    np.testing.assert_allclose(S.edge_weights, [[0.2 / 6] * 3, [1.0 / 6] * 3], rtol=1e-14)
    for b in S.element_hessians(X, project=False):
        assert np.linalg.eigvalsh(b).min() >= -1e-13 * np.abs(b).max()
    np.testing.assert_allclose(S.laplacian().toarray(), area_laplacian(X, T).toarray(), atol=1e-14)
    # set_weights recomputes areas from the given shape (here: everything scaled by 2 → areas x 4)
    S.set_weights(2.0 * X)
    np.testing.assert_allclose(S.edge_weights, [[0.8 / 6] * 3, [4.0 / 6] * 3], rtol=1e-14)
    with pytest.raises(ValueError, match="weights must be one of"):
        LaplacianSmoothing(X, T, 1.0, weights="uniform")


def test_obtuse_triangle_blocks_are_psd_and_clamping_is_optional() -> None:
    X = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, -1.0, 0.0]])  # obtuse at vertex 2
    T = np.array([[0, 1, 2], [1, 0, 3]])
    S = LaplacianSmoothing(X, T, 1.0)
    assert S.edge_weights.min() < -0.1  # a negative cot weight ...
    for b in S.element_hessians(X, project=False):
        assert np.linalg.eigvalsh(b).min() >= -1e-13 * np.abs(b).max()  # ... yet a PSD block (P1 stiffness)
    np.testing.assert_allclose(S.laplacian().toarray(), cotangent_laplacian(X, T).toarray(), atol=1e-14)
    C = LaplacianSmoothing(X, T, 1.0, clamp_negative=True)
    assert np.all(C.edge_weights >= 0)
    Lc = C.laplacian().toarray()
    assert np.all(Lc - np.diag(np.diag(Lc)) >= 0)  # M-matrix off-diagonals
    for b in C.element_hessians(X, project=False):
        assert np.linalg.eigvalsh(b).min() >= -1e-13 * np.abs(b).max()


def test_normal_force_is_linear_along_frozen_normals() -> None:
    X, T = _sphere()
    F = NormalForce(T, len(X), beta=0.7)
    F.update(X)
    np.testing.assert_allclose(F.normals, vertex_normals(X, T) / 3.0)
    x = X * 1.1
    assert F.value(x) == pytest.approx(-0.7 * np.sum(F.normals * x), rel=1e-13)
    np.testing.assert_allclose(F.gradient(x), -0.7 * F.normals.ravel())
    calls = []
    _v, g = F.value_gradient_hessian_groups(x, lambda first, b: calls.append(first))
    assert not calls and F.element_dofs().shape == (0, 3)
    # a descent step moves the sphere outward (the flow inflates it)
    assert np.all(np.einsum("ij,ij->i", -g.reshape(-1, 3), X) > 0)


def test_lumped_unit_normal_force_points_outward_with_lumped_area_magnitude() -> None:
    X, T = _sphere()
    X = X + np.array([0.3, -2.0, 1.0])  # off the origin: outward is relative to the centroid
    c = X.mean(axis=0)
    m = vertex_areas(X, T)
    for weighting in ("area", "lumped_unit"):
        F = NormalForce(T, len(X), beta=1.0, weighting=weighting)
        F.update(X)
        assert np.all(np.einsum("ij,ij->i", F.normals, X - c) > 0)
    np.testing.assert_allclose(np.linalg.norm(F.normals, axis=1), m, rtol=1e-13)
    np.testing.assert_allclose(F.normals, m[:, None] * vertex_normals(X, T, unit=True), rtol=1e-13)
    # the default is unchanged: Σ_t A_t n̂_t / 3, no longer than the lumped area
    D = NormalForce(T, len(X), beta=1.0)
    D.update(X.ravel())
    assert D.weighting == "area"
    np.testing.assert_allclose(D.normals, vertex_normals(X, T) / 3.0)
    assert np.all(np.linalg.norm(D.normals, axis=1) <= m * (1 + 1e-12))
    with pytest.raises(ValueError, match="weighting must be one of"):
        NormalForce(T, len(X), beta=1.0, weighting="unit")


def test_area_smoothing_at_gamma_s_is_the_authors_smoothing_step_at_h_s() -> None:
    """The authors' flow adds h·(−½xᵀL_a x) to the step at h = smoothIntensity s, with (L_a x)_i accumulating
    (A_t/6)(x_j + x_k − 2x_i) over the triangles t = (i, j, k) of the start shape; with idp's h = 1 that is
    γ = s with ``weights="area"``."""
    rng = np.random.default_rng(7)
    X, T = _flat(4, 0.08)
    X[:, 2] = 0.1 * np.sin(3 * X[:, 0])
    A = _face_areas(X, T)
    x = X + 0.05 * rng.standard_normal(X.shape)
    La_x = np.zeros_like(x)
    for c in range(3):
        i, j, k = T[:, c], T[:, (c + 1) % 3], T[:, (c + 2) % 3]
        np.add.at(La_x, i, (A / 6.0)[:, None] * (x[j] + x[k] - 2.0 * x[i]))
    s = 0.7
    S = LaplacianSmoothing(X, T, s, weights="area")
    np.testing.assert_allclose(S.gradient(x.ravel()), (-s * La_x).ravel(), atol=1e-13)
    assert S.value(x.ravel()) == pytest.approx(-0.5 * s * np.sum(x * La_x), rel=1e-12)
