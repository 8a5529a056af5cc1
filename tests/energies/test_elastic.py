"""Tests of idp.energies.elastic: derivatives by finite differences, the analytic PSD projection
against an eigh-clamped reference, rest-state / barrier / rest-scale behaviour, and the numba
kernels against the numpy reference."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from idp.energies import _elastic_kernels as K
from idp.energies.elastic import ElasticEnergy, lame_parameters, rest_frames

MODELS = ["neo_hookean", "symmetric_dirichlet"]
DIMS = [3, 2]
MATERIALS = list(itertools.product([1e3, 1e5], [0.0, 0.3, 0.45]))


# ------------------------------------------------------------------ mesh builders


def _rotation(d: int, rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(d, d)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def _orient(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Swap the first two vertices of negatively oriented elements."""
    T = T.copy()
    Dm = np.transpose(X[T[:, 1:]] - X[T[:, :1]], (0, 2, 1))
    neg = np.linalg.det(Dm) < 0
    T[neg, 0], T[neg, 1] = T[neg, 1].copy(), T[neg, 0].copy()
    return T


def random_simplices(d: int, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` disjoint, well-shaped, randomly rotated/scaled simplices."""
    base = np.vstack([np.zeros(d), np.eye(d)])
    verts = []
    for i in range(count):
        s = base + 0.15 * rng.normal(size=base.shape)
        s = s @ _rotation(d, rng).T * rng.uniform(0.5, 2.0) + 5.0 * i
        verts.append(s)
    X = np.vstack(verts)
    T = np.arange(count * (d + 1)).reshape(count, d + 1)
    return X, _orient(X, T)


def box_mesh(d: int, n: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Structured [0,1]^d grid of n^d cells split into simplices (6 tets / 2 triangles per cell)."""
    g = np.linspace(0.0, 1.0, n + 1)
    X = np.stack(np.meshgrid(*([g] * d), indexing="ij"), axis=-1).reshape(-1, d)
    idx = np.arange((n + 1) ** d).reshape((n + 1,) * d)
    cells = []
    for c in itertools.product(range(n), repeat=d):
        corner = lambda off: idx[tuple(np.add(c, off))]  # noqa: E731
        for perm in itertools.permutations(range(d)):
            path = [np.zeros(d, int)]
            for ax in perm:
                nxt = path[-1].copy()
                nxt[ax] = 1
                path.append(nxt)
            cells.append([corner(p) for p in path])
    T = np.array(cells, dtype=np.int64)
    return X, _orient(X, T)


def test_meshes(d: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(100 + d)
    return [random_simplices(d, 4, rng), box_mesh(d)]


test_meshes.__test__ = False  # helper, not a test


def deform(X: np.ndarray, T: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    d = X.shape[1]
    if kind == "perturb":
        Y = X + 0.08 * rng.normal(size=X.shape)
    elif kind == "expand":  # strong anisotropic growth: NH scaling block indefinite for large nu
        Y = X @ (_rotation(d, rng) @ np.diag([2.6, 2.4, 1.4][:d] if d == 3 else [3.0, 2.6])).T
        Y = Y + 0.02 * rng.normal(size=X.shape)
    elif kind == "stretch":
        S = np.diag([3.0, 0.35, 1.7][:d])
        Y = X @ (_rotation(d, rng) @ S).T + 0.02 * rng.normal(size=X.shape)
    else:  # "compress": strong uniform compression plus shear
        A = 0.3 * np.eye(d)
        A[0, 1] = 0.25
        Y = X @ A.T + 0.005 * rng.normal(size=X.shape)
    # keep every element positively oriented
    for _ in range(30):
        Dm = np.transpose(Y[T[:, 1:]] - Y[T[:, :1]], (0, 2, 1))
        if np.all(np.linalg.det(Dm) > 0):
            return np.ascontiguousarray(Y)
        Y = 0.5 * (Y + X)
    raise AssertionError("could not build a positive deformation")


def assemble(E: ElasticEnergy, H: np.ndarray) -> sp.csr_matrix:
    dofs = E.element_dofs()
    k = dofs.shape[1]
    rows = np.repeat(dofs, k, axis=1).ravel()
    cols = np.tile(dofs, (1, k)).ravel()
    n = E.num_vertices * E.dim
    return sp.coo_matrix((H.ravel(), (rows, cols)), shape=(n, n)).tocsr()


KINDS = ["perturb", "stretch", "compress", "expand"]
CASES = list(itertools.product(MODELS, DIMS, KINDS))


# ------------------------------------------------------------------ finite differences


@pytest.mark.parametrize("model,d,kind", CASES)
def test_gradient_matches_finite_differences(model: str, d: int, kind: str) -> None:
    rng = np.random.default_rng(1)
    for X, T in test_meshes(d):
        x = deform(X, T, kind, rng)
        for Ey, nu in MATERIALS:
            E = ElasticEnergy(model, X, T, Ey, nu)
            g = E.gradient(x)
            h = 1e-6
            flat = x.ravel()
            fd = np.empty_like(flat)
            for i in range(flat.size):
                e = np.zeros_like(flat)
                e[i] = h
                fd[i] = (E.value(flat + e) - E.value(flat - e)) / (2 * h)
            err = np.linalg.norm(fd - g) / np.linalg.norm(g)
            assert err < 1e-6, (model, d, kind, Ey, nu, err)


@pytest.mark.parametrize("model,d,kind", CASES)
def test_exact_hessian_matches_finite_differences(model: str, d: int, kind: str) -> None:
    rng = np.random.default_rng(2)
    for X, T in test_meshes(d):
        x = deform(X, T, kind, rng).ravel()
        for Ey, nu in MATERIALS:
            E = ElasticEnergy(model, X, T, Ey, nu)
            Hm = assemble(E, E.element_hessians(x, project=False))
            h = 1e-6
            for _ in range(3):
                v = rng.normal(size=x.size)
                fd = (E.gradient(x + h * v) - E.gradient(x - h * v)) / (2 * h)
                Hv = Hm @ v
                err = np.linalg.norm(fd - Hv) / np.linalg.norm(Hv)
                assert err < 1e-5, (model, d, kind, Ey, nu, err)
            # the fused pass gives the same numbers
            f, g, Hf = E.value_gradient_hessian(x, project=False)
            assert f == pytest.approx(E.value(x), rel=1e-14)
            np.testing.assert_allclose(g, E.gradient(x), rtol=0, atol=1e-14 * np.abs(g).max())
            np.testing.assert_array_equal(Hf, E.element_hessians(x, project=False))


# ------------------------------------------------------------------ projection vs eigh


def _dP_dF(model: str, F: np.ndarray, mu: float, lam: float, w: float) -> np.ndarray:
    """Exact d vec(P) / d vec(F) (row-major vec) derived directly in F, independent of the SVD path."""
    d = F.shape[0]
    Fi = np.linalg.inv(F)
    G = Fi.T
    lnJ = np.log(np.linalg.det(F))
    Kmat = np.zeros((d * d, d * d))
    for p in range(d):
        for q in range(d):
            dF = np.zeros((d, d))
            dF[p, q] = 1.0
            dG = -G @ dF.T @ G
            if model == "neo_hookean":
                dP = mu * dF + lam * np.trace(Fi @ dF) * G + (lam * lnJ - mu) * dG
            else:
                dP = 2 * w * (dF - (dG @ G.T @ G + G @ dG.T @ G + G @ G.T @ dG))
            Kmat[:, p * d + q] = dP.ravel()
    return Kmat


def _F_cases(d: int, rng: np.random.Generator) -> list[np.ndarray]:
    R1, R2 = _rotation(d, rng), _rotation(d, rng)
    if d == 3:
        sigmas = [
            [1, 1, 1],
            [2.0, 2.0, 0.5],
            [1.5, 0.4, 0.4],
            [0.7, 0.7, 0.7],
            [2.5, 1.1, 0.3],
            [1.3, 1.3 + 1e-9, 0.8],
            [0.05, 0.05, 0.05],
            [4.0, 0.2, 0.1],
            [2.5, 2.5, 1.3],
        ]
    else:
        sigmas = [[1, 1], [2.0, 2.0], [0.3, 0.3], [2.5, 0.3], [1.3, 1.3 + 1e-9], [4.0, 0.1], [3.0, 2.8]]
    out = [np.eye(d)]
    for s in sigmas:
        out.append(R1 @ np.diag(s) @ R2.T)
        out.append(np.diag(s).astype(float))
    return out


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_projection_equals_eigh_clamped_exact_hessian(model: str, d: int) -> None:
    rng = np.random.default_rng(3)
    for F in _F_cases(d, rng):
        X, T = random_simplices(d, 1, rng)
        Dm = (X[T[0, 1:]] - X[T[0, 0]]).T
        x = X.copy()
        x[T[0, 1:]] = X[T[0, 0]] + (F @ Dm).T
        for Ey, nu in [(1e3, 0.0), (1e5, 0.45), (1e4, 0.3)]:
            w = 7.0 * Ey
            E = ElasticEnergy(model, X, T, Ey, nu, weight=w if model != "neo_hookean" else None)
            mu, lam = lame_parameters(Ey, nu)
            Kex = _dP_dF(model, F, mu, lam, w)
            np.testing.assert_allclose(Kex, Kex.T, atol=1e-9 * np.abs(Kex).max())
            ev, Q = np.linalg.eigh(0.5 * (Kex + Kex.T))
            Kproj = (Q * np.maximum(ev, 0)) @ Q.T
            B = K.deformation_map(E.Dm_inv)[0]
            v = E.volumes[0]
            for project, Kref in ((True, Kproj), (False, Kex)):
                Href = v * B.T @ Kref @ B
                H = E.element_hessians(x, project=project)[0]
                err = np.abs(H - Href).max() / np.abs(Href).max()
                assert err < 1e-6, (model, d, F, project, err)


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_projected_hessians_are_symmetric_psd(model: str, d: int) -> None:
    rng = np.random.default_rng(4)
    indefinite = False
    for X, T in test_meshes(d):
        for kind in KINDS:
            x = deform(X, T, kind, rng)
            E = ElasticEnergy(model, X, T, 1e5, 0.45)
            H = E.element_hessians(x, project=True)
            assert np.all(np.isfinite(H))
            np.testing.assert_array_equal(H, np.transpose(H, (0, 2, 1)))
            ev = np.linalg.eigvalsh(H)
            assert np.all(ev.min(axis=1) >= -1e-8 * np.abs(ev).max(axis=1))
            ex = np.linalg.eigvalsh(E.element_hessians(x, project=False))
            indefinite |= bool(ex.min() < -1e-6 * np.abs(ex).max())
    # the exact Hessian is indefinite somewhere (strong compression), so projection mattered
    assert indefinite


# ------------------------------------------------------------------ behaviour


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_rest_state_inversion_and_rest_scale(model: str, d: int) -> None:
    X, T = box_mesh(d)
    E = ElasticEnergy(model, X, T, 1e4, 0.3)
    assert abs(E.value(X)) < 1e-9
    assert np.abs(E.gradient(X)).max() < 1e-9
    assert E.min_jacobian(X) == pytest.approx(1.0)
    # invert one element: move vertex 0 of element 0 through its opposite facet
    x = X.copy()
    t0 = T[0]
    centroid = X[t0[1:]].mean(axis=0)
    x[t0[0]] = centroid + 0.5 * (centroid - X[t0[0]])
    assert E.value(x) == np.inf
    assert E.min_jacobian(x) < 0
    # growth: the rest shape doubles, so X is compressed and 2X is the new rest state
    E.set_rest_scale(2.0)
    assert E.value(X) > 0 and np.linalg.norm(E.gradient(X)) > 1.0
    assert abs(E.value(2 * X)) < 1e-8
    assert np.abs(E.gradient(2 * X)).max() < 1e-8
    vol0 = E.volumes.copy()
    s = np.array([1.0, 2.0, 3.0][:d])
    E.set_rest_scale(s)
    np.testing.assert_array_equal(E.volumes, vol0)
    assert np.abs(E.gradient(X * s)).max() < 1e-8
    assert np.linalg.norm(E.gradient(X)) > 1.0


def test_per_element_materials_add_up() -> None:
    X, T = box_mesh(3)
    rng = np.random.default_rng(5)
    x = deform(X, T, "perturb", rng)
    Ey = np.where(np.arange(len(T)) % 2 == 0, 1e3, 1e5)
    nu = np.where(np.arange(len(T)) % 3 == 0, 0.45, 0.2)
    E = ElasticEnergy("neo_hookean", X, T, Ey, nu)
    parts = [ElasticEnergy("neo_hookean", X, T[i : i + 1], Ey[i], nu[i]) for i in range(len(T))]
    assert E.value(x) == pytest.approx(sum(p.value(x) for p in parts), rel=1e-12)
    np.testing.assert_allclose(
        E.gradient(x), sum(p.gradient(x) for p in parts), rtol=1e-10, atol=1e-10 * np.abs(E.gradient(x)).max()
    )
    # symmetric Dirichlet default weight = mu/4 (matches NH small-strain shear stiffness)
    S = ElasticEnergy("symmetric_dirichlet", X, T, Ey, nu)
    np.testing.assert_allclose(S.weight, E.mu / 4)


def test_validation_errors() -> None:
    X, T = box_mesh(2)
    bad = T.copy()
    bad[3, [0, 1]] = bad[3, [1, 0]]
    with pytest.raises(ValueError, match="element 3"):
        rest_frames(X, bad)
    with pytest.raises(ValueError):
        lame_parameters(-1.0, 0.3)
    with pytest.raises(ValueError):
        lame_parameters(1.0, 0.5)
    with pytest.raises(ValueError):
        ElasticEnergy("stvk", X, T, 1.0, 0.3)
    mu, lam = lame_parameters(1e4, 0.25)
    assert mu == pytest.approx(4000.0) and lam == pytest.approx(4000.0)
    Dm_inv, vol = rest_frames(X, T)
    assert vol.sum() == pytest.approx(1.0)


# ------------------------------------------------------------------ numba vs numpy


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_kernel_matches_numpy_reference(model: str, d: int) -> None:
    rng = np.random.default_rng(6)
    for X, T in test_meshes(d):
        for kind in KINDS:
            x = deform(X, T, kind, rng)
            m = len(T)
            E = ElasticEnergy(model, X, T, rng.uniform(1e3, 1e5, m), rng.uniform(0, 0.45, m))
            E.set_rest_scale(rng.uniform(0.8, 1.2, d))
            for project in (True, False):
                k = (d + 1) * d
                e, g, H = np.empty(m), np.empty((m, k)), np.empty((m, k, k))
                K.element_terms(
                    x, E.elements, E.Dm_inv, E.volumes, E._model_id, E._pa, E._pb, True, True, project, e, g, H
                )
                er, gr, Hr = K.element_terms_reference(
                    x, E.elements, E.Dm_inv, E.volumes, E._model_id, E._pa, E._pb, project
                )
                np.testing.assert_allclose(e, er, rtol=1e-12, atol=1e-12 * np.abs(er).max())
                scale_g = np.abs(gr).max(axis=1)[:, None]
                assert np.all(np.abs(g - gr) <= 1e-12 * scale_g)
                scale_H = np.abs(Hr).max(axis=(1, 2))[:, None, None]
                assert np.all(np.abs(H - Hr) <= 1e-12 * scale_H)
            f, gg, _ = E.value_gradient_hessian(x)
            assert f == pytest.approx(er.sum(), rel=1e-12)
            ref = np.zeros(E.num_vertices * d)
            np.add.at(ref, E.element_dofs().ravel(), gr.ravel())
            np.testing.assert_allclose(gg, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("d", DIMS)
def test_hessians_streamed_in_groups_equal_the_whole_array(d: int) -> None:
    """``value_gradient_hessian_groups`` hands every element's block once, in order, with the same values."""
    X, T = box_mesh(d)
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.4)
    x = deform(X, T, "stretch", np.random.default_rng(7))
    f, g, H = E.value_gradient_hessian(x)
    seen = []
    fg, gg = E.value_gradient_hessian_groups(x, lambda first, blocks: seen.append((first, blocks.copy())), group=5)
    assert fg == pytest.approx(f, rel=1e-13)
    np.testing.assert_allclose(gg, g, rtol=0, atol=1e-13 * np.abs(g).max())
    assert [first for first, _ in seen] == list(range(0, len(T), 5))
    np.testing.assert_array_equal(np.concatenate([b for _, b in seen]), H)
