"""Tests of idp.energies.elastic: derivatives by finite differences, the analytic PSD projection
against an eigh-clamped reference, rest-state / barrier / rest-frame behaviour, and the numba
kernels against the numpy reference.  Every model (NH, SD, ARAP, StVK) in 2D and 3D; the
non-barrier models (ARAP, StVK) also on inverted elements."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from idp.energies import _elastic_kernels as K
from idp.energies.elastic import ElasticEnergy, lame_parameters, rest_frames

BARRIER = ["neo_hookean", "symmetric_dirichlet"]
NON_BARRIER = ["arap", "stvk"]
MODELS = BARRIER + NON_BARRIER
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


# helper, not a test (pytest reads __test__ on any object; mypy knows no such function attribute)
test_meshes.__test__ = False  # type: ignore[attr-defined]


def signed_singular_values(F: np.ndarray) -> np.ndarray:
    """(m,d) singular values in the kernels' convention: descending, the last one carries sign(det F)."""
    sig = np.linalg.svd(F, compute_uv=False)
    sig[:, -1] *= np.where(np.linalg.det(F) < 0, -1.0, 1.0)
    return sig


def deformation_gradients(X: np.ndarray, T: np.ndarray, Y: np.ndarray) -> np.ndarray:
    Dm = np.transpose(X[T[:, 1:]] - X[T[:, :1]], (0, 2, 1))
    Ds = np.transpose(Y[T[:, 1:]] - Y[T[:, :1]], (0, 2, 1))
    return Ds @ np.linalg.inv(Dm)


def deform(X: np.ndarray, T: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    d = X.shape[1]
    if kind in INVERTING_KINDS:
        # for the non-barrier models: some or all elements inverted, kept away from ARAP's kink s_i + s_j = 0
        # (where the polar rotation jumps) so finite differences are meaningful
        for _ in range(50):
            if kind == "invert":  # a reflection with anisotropic stretch: every element inverted
                Y = X @ (_rotation(d, rng) @ np.diag([1.8, 1.2, -0.6][:d] if d == 3 else [1.6, -0.5])).T
                Y = Y + 0.02 * rng.normal(size=X.shape)
            else:  # "tangle": element 0's first vertex pushed through its facet, plus noise: a mix of signs
                Y = X + 0.05 * rng.normal(size=X.shape)
                t0 = T[0]
                centroid = Y[t0[1:]].mean(axis=0)
                Y[t0[0]] = centroid + 0.6 * (centroid - Y[t0[0]])
            sig = signed_singular_values(deformation_gradients(X, T, Y))
            pair = sig[:, :, None] + sig[:, None, :]
            if np.all(pair[:, ~np.eye(d, dtype=bool)] > 0.02):
                assert np.any(sig[:, -1] < 0)
                return np.ascontiguousarray(Y)
        raise AssertionError("could not build an inverted deformation away from the ARAP kink")
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
INVERTING_KINDS = ["invert", "tangle"]


def kinds(model: str) -> list[str]:
    """Deformations a model is tested on: inverted elements only for the non-barrier models."""
    return KINDS + (INVERTING_KINDS if model in NON_BARRIER else [])


CASES = [(model, d, kind) for model in MODELS for d in DIMS for kind in kinds(model)]


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
            He = E.element_hessians(x, project=False)
            np.testing.assert_allclose(Hf, He, rtol=0, atol=1e-14 * np.abs(He).max())  # rounding level


# ------------------------------------------------------------------ projection vs eigh


def _polar(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F = R S with R a rotation (det +1) and S symmetric (indefinite when det F < 0)."""
    U, s, Vt = np.linalg.svd(F)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        U[:, -1] *= -1.0
        s[-1] *= -1.0
    return U @ Vt, Vt.T @ np.diag(s) @ Vt


def _dP_dF(model: str, F: np.ndarray, mu: float, lam: float, w: float) -> np.ndarray:
    """Exact d vec(P) / d vec(F) (row-major vec) derived directly in F, independent of the eigensystem path.

    ARAP: P = 2 mu (F - R), dR = R ω with ω antisymmetric from differentiating F = R S:
    ω S + S ω = Rᵀ dF − dFᵀ R, solved over antisymmetric ω (the operator is singular on symmetric
    matrices when S is, at det F = 0).  StVK: P = F (2 mu E + lam tr(E) I)."""
    d = F.shape[0]
    if model in ("neo_hookean", "symmetric_dirichlet"):
        Fi = np.linalg.inv(F)
        G = Fi.T
        lnJ = np.log(np.linalg.det(F))
    if model == "arap":
        R, Ssym = _polar(F)
        pairs = list(itertools.combinations(range(d), 2))
        basis = np.zeros((d * d, len(pairs)))  # vec of e_i e_j^T - e_j e_i^T
        for c, (i, j) in enumerate(pairs):
            basis[i * d + j, c], basis[j * d + i, c] = 1.0, -1.0
        sylvester = (np.kron(Ssym, np.eye(d)) + np.kron(np.eye(d), Ssym.T)) @ basis
    E = 0.5 * (F.T @ F - np.eye(d))
    Kmat = np.zeros((d * d, d * d))
    for p in range(d):
        for q in range(d):
            dF = np.zeros((d, d))
            dF[p, q] = 1.0
            if model == "neo_hookean":
                dG = -G @ dF.T @ G
                dP = mu * dF + lam * np.trace(Fi @ dF) * G + (lam * lnJ - mu) * dG
            elif model == "symmetric_dirichlet":
                dG = -G @ dF.T @ G
                dP = 2 * w * (dF - (dG @ G.T @ G + G @ dG.T @ G + G @ G.T @ dG))
            elif model == "arap":
                coef = np.linalg.lstsq(sylvester, (R.T @ dF - dF.T @ R).ravel(), rcond=None)[0]
                omega = (basis @ coef).reshape(d, d)
                dP = 2 * mu * (dF - R @ omega)
            else:
                dE = 0.5 * (dF.T @ F + F.T @ dF)
                dP = dF @ (2 * mu * E + lam * np.trace(E) * np.eye(d)) + F @ (
                    2 * mu * dE + lam * np.trace(dE) * np.eye(d)
                )
            Kmat[:, p * d + q] = dP.ravel()
    return Kmat


def _F_cases(d: int, rng: np.random.Generator, inverted: bool = False) -> list[np.ndarray]:
    """Deformation gradients with chosen singular values (repeated, near-repeated, extreme), and with
    ``inverted`` also reflected / degenerate ones (signed last singular value <= 0, away from s_i + s_j = 0)."""
    R1, R2 = _rotation(d, rng), _rotation(d, rng)
    if d == 3:
        sigmas: list[list[float]] = [
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
    if inverted and d == 3:
        sigmas += [[2.0, 1.2, -0.6], [1.3, 1.3, -0.4], [1.3, 1.3 + 1e-9, -0.8], [1.2, 0.6, 0.0], [0.5, 0.3, -0.1]]
    elif inverted:
        sigmas += [[1.5, -0.4], [0.7, -0.2], [1.0, 0.0], [3.0, -2.0]]
    out = [np.eye(d)]
    for s in sigmas:
        out.append(R1 @ np.diag(s) @ R2.T)
        out.append(np.diag(s).astype(float))
    return out


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_projection_equals_eigh_clamped_exact_hessian(model: str, d: int) -> None:
    rng = np.random.default_rng(3)
    for F in _F_cases(d, rng, inverted=model in NON_BARRIER):
        X, T = random_simplices(d, 1, rng)
        Dm = (X[T[0, 1:]] - X[T[0, 0]]).T
        x = X.copy()
        x[T[0, 1:]] = X[T[0, 0]] + (F @ Dm).T
        for Ey, nu in [(1e3, 0.0), (1e5, 0.45), (1e4, 0.3)]:
            w = 7.0 * Ey
            E = ElasticEnergy(model, X, T, Ey, nu, weight=w if model == "symmetric_dirichlet" else None)
            mu, lam = lame_parameters(Ey, nu)
            Kex = _dP_dF(model, F, float(mu), float(lam), w)
            np.testing.assert_allclose(Kex, Kex.T, atol=1e-9 * np.abs(Kex).max())
            ev, Q = np.linalg.eigh(0.5 * (Kex + Kex.T))
            Kproj = (Q * np.maximum(ev, 0)) @ Q.T
            B = K.deformation_map(E.Dm_inv)[0]
            v = E.volumes[0]
            scale = np.abs(v * B.T @ Kex @ B).max()  # the projection of a fully compressed StVK element is 0
            for project, Kref in ((True, Kproj), (False, Kex)):
                Href = v * B.T @ Kref @ B
                H = E.element_hessians(x, project=project)[0]
                err = np.abs(H - Href).max() / scale
                assert err < 1e-6, (model, d, F, project, err)


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_projected_hessians_are_symmetric_psd(model: str, d: int) -> None:
    rng = np.random.default_rng(4)
    indefinite = False
    for X, T in test_meshes(d):
        for kind in kinds(model):
            x = deform(X, T, kind, rng)
            E = ElasticEnergy(model, X, T, 1e5, 0.45)
            H = E.element_hessians(x, project=True)
            assert np.all(np.isfinite(H))
            np.testing.assert_array_equal(H, np.transpose(H, (0, 2, 1)))  # exact: the kernel mirrors one triangle
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
    assert E.min_jacobian(x) < 0
    if model in BARRIER:
        assert E.guards_inversion
        assert E.value(x) == np.inf
    else:
        # non-barrier: finite everywhere, no inversion filter in the line search
        assert not E.guards_inversion
        f, g, H = E.value_gradient_hessian(x, project=False)
        assert 0 < f < np.inf and np.all(np.isfinite(g)) and np.all(np.isfinite(H))
        assert np.all(np.isfinite(E.element_hessians(x, project=True)))
        assert E.max_step(x, -x) == 1.0
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
    with pytest.raises(ValueError, match="unknown elastic model"):
        ElasticEnergy("corotated", X, T, 1.0, 0.3)
    with pytest.raises(ValueError, match="arap weight"):
        ElasticEnergy("arap", X, T, 1.0, 0.3, weight=-1.0)
    mu, lam = lame_parameters(1e4, 0.25)
    assert mu == pytest.approx(4000.0) and lam == pytest.approx(4000.0)
    _, vol = rest_frames(X, T)
    assert vol.sum() == pytest.approx(1.0)


# ------------------------------------------------------------------ numba vs numpy


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_kernel_matches_numpy_reference(model: str, d: int) -> None:
    rng = np.random.default_rng(6)
    for X, T in test_meshes(d):
        for kind in kinds(model):
            x = deform(X, T, kind, rng)
            m = len(T)
            E = ElasticEnergy(model, X, T, rng.uniform(1e3, 1e5, m), rng.uniform(0, 0.45, m))
            E.set_rest_scale(rng.uniform(0.8, 1.2, d))
            for project in (True, False):
                k = (d + 1) * d
                e, g, H = np.empty(m), np.empty((m, k)), np.empty((m, k, k))
                K.element_terms(
                    x, E.elements, E.Dm_inv, E.volumes, E._model_id, E._pa, E._pb, True, True, project, 1.0, e, g, H
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
    # same kernel on slices of the element arrays: agreement to rounding (not asserted bit for bit)
    np.testing.assert_allclose(np.concatenate([b for _, b in seen]), H, rtol=0, atol=1e-14 * np.abs(H).max())


# ------------------------------------------------------------------ rest frames: transform, bake, deform


@pytest.mark.parametrize("d", DIMS)
def test_set_rest_transform_of_a_diagonal_equals_set_rest_scale(d: int) -> None:
    X, T = box_mesh(d)
    A = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    B = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    for s in (np.array([1.0, 2.0, 3.0][:d]), np.full(d, 1.7)):
        A.set_rest_scale(s if s[0] != s[-1] else float(s[0]))
        B.set_rest_transform(np.diag(s))
        # set_rest_scale(s) is set_rest_transform(diag(s)): the same code on the same input, so identical
        np.testing.assert_array_equal(A.Dm_inv, B.Dm_inv)
        np.testing.assert_array_equal(A.rest_frames_inverse, B.rest_frames_inverse)
        np.testing.assert_array_equal(A.rest_transform, np.diag(s))
        np.testing.assert_array_equal(A.volumes, B.volumes)
    # set_rest_scale of the original frames: as before, inv(diag(s) Dm0), volumes untouched
    Dm0 = np.linalg.inv(rest_frames(X, T)[0])
    np.testing.assert_allclose(A.Dm_inv, np.linalg.inv(1.7 * Dm0), rtol=1e-14)


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_rest_transform_anisotropic_and_per_element(model: str, d: int) -> None:
    X, T = box_mesh(d)
    E = ElasticEnergy(model, X, T, 1e4, 0.3)
    rng = np.random.default_rng(8)
    # a shared anisotropic transform (rotation x stretch x shear, det > 0): A X is the new rest state
    Amat = _rotation(d, rng) @ np.diag([1.5, 0.7, 1.2][:d]) + 0.1 * np.triu(np.ones((d, d)), 1)
    E.set_rest_transform(Amat)
    x = X @ Amat.T
    assert abs(E.value(x)) < 1e-9 and np.abs(E.gradient(x)).max() < 1e-8
    assert E.value(X) > 1.0
    # per element: element t's rest frame scaled by s_t (per-region growth) equals a per-element Dm_inv
    s = rng.uniform(0.5, 2.0, len(T))
    E.set_rest_transform(s[:, None, None] * np.eye(d))
    ref = np.linalg.inv(s[:, None, None] * np.linalg.inv(rest_frames(X, T)[0]))
    np.testing.assert_allclose(E.rest_frames_inverse, ref, rtol=1e-13)


def test_rest_transform_validation() -> None:
    X, T = box_mesh(3)
    E = ElasticEnergy("arap", X, T, 1e4, 0.3)
    with pytest.raises(ValueError, match="shape"):
        E.set_rest_transform(np.eye(2))
    with pytest.raises(ValueError, match="finite"):
        E.set_rest_transform(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="det > 0"):
        E.set_rest_transform(np.diag([1.0, 1.0, -1.0]))
    per = np.repeat(np.eye(3)[None], len(T), axis=0)
    per[4, 0, 0] = 0.0
    with pytest.raises(ValueError, match="element 4"):
        E.set_rest_transform(per)
    with pytest.raises(ValueError, match="rest scale"):
        E.set_rest_scale(0.0)


@pytest.mark.parametrize("model,d", list(itertools.product(MODELS, DIMS)))
def test_bake_makes_the_current_shape_the_rest_shape(model: str, d: int) -> None:
    X, T = box_mesh(d)
    rng = np.random.default_rng(9)
    E = ElasticEnergy(model, X, T, 1e4, 0.3)
    E.set_rest_scale(np.array([1.3, 0.8, 1.1][:d]))
    x = deform(X, T, "stretch", rng)
    g_before = np.abs(E.gradient(x)).max()
    assert E.value(x) > 1.0
    E.bake(x)
    # x is now an equilibrium with zero energy, to rounding (finite-difference level)
    assert abs(E.value(x)) < 1e-9 * E.volumes.sum() * E.mu.max()
    assert np.abs(E.gradient(x)).max() < 1e-9 * g_before
    np.testing.assert_array_equal(E.rest_transform, np.eye(d))
    xe = np.transpose(x[T[:, 1:]] - x[T[:, :1]], (0, 2, 1))
    np.testing.assert_allclose(E.volumes, np.linalg.det(xe) / (6.0 if d == 3 else 2.0), rtol=1e-13)
    np.testing.assert_array_equal(E.base_rest_frames, xe)  # exact: one IEEE subtraction per entry, as here
    # the rest scale now acts on the baked shape (growth of the baked shape), volume weights stay
    vol = E.volumes.copy()
    E.set_rest_scale(2.0)
    assert abs(E.value(2.0 * x)) < 1e-8 * E.volumes.sum() * E.mu.max()
    np.testing.assert_array_equal(E.volumes, vol)
    # a shape with an inverted element cannot become the rest shape
    y = X.copy()
    centroid = X[T[0, 1:]].mean(axis=0)
    y[T[0, 0]] = centroid + 0.5 * (centroid - X[T[0, 0]])
    with pytest.raises(ValueError, match="element 0"):
        E.bake(y)


@pytest.mark.parametrize("d", DIMS)
def test_deform_rest_frames_keeps_the_transform_on_top(d: int) -> None:
    X, T = box_mesh(d)
    rng = np.random.default_rng(10)
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    base0 = E.base_rest_frames.copy()
    Tr = np.diag([1.2, 0.9, 1.4][:d])
    E.set_rest_scale(np.diag(Tr))
    which = np.array([1, 3, 4])
    G = np.stack([np.eye(d) + 0.2 * rng.normal(size=(d, d)) for _ in which])
    E.deform_rest_frames(G, which)
    # the effective frames of the chosen elements became G (T Dm); the others are unchanged bit for bit
    np.testing.assert_allclose(np.linalg.inv(E.Dm_inv[which]), G @ (Tr @ base0[which]), rtol=1e-12, atol=1e-14)
    rest = np.setdiff1d(np.arange(len(T)), which)
    np.testing.assert_array_equal(E.base_rest_frames[rest], base0[rest])
    np.testing.assert_array_equal(E.rest_transform, Tr)
    # a later rest scale acts on the deformed base: Dm = T' T⁻¹ G T Dm0
    E.set_rest_scale(1.0)
    np.testing.assert_allclose(
        np.linalg.inv(E.Dm_inv[which]), np.linalg.solve(Tr, G @ Tr @ base0[which]), rtol=1e-12, atol=1e-14
    )
    with pytest.raises(ValueError, match="shape"):
        E.deform_rest_frames(G)


@pytest.mark.parametrize("d", DIMS)
def test_an_unchanged_rest_transform_keeps_frames_that_match_it(d: int) -> None:
    """Setting the rest scale or transform it already has skips the recomputation, after any mutator of the base
    frames too: Dm_inv always equals inv(T Dm_base) (growth scripts set their held scale every step)."""
    X, T = box_mesh(d)
    rng = np.random.default_rng(12)
    E = ElasticEnergy("neo_hookean", X, T, 1e4, 0.3)
    s = np.array([1.2, 0.9, 1.4][:d])

    def expected() -> np.ndarray:
        return np.linalg.inv(E.rest_transform @ E.base_rest_frames)

    E.set_rest_scale(s)
    first = E.Dm_inv
    E.set_rest_scale(s.copy())
    assert E.Dm_inv is first  # not recomputed
    E.set_rest_transform(np.diag(s))
    assert E.Dm_inv is first
    which = np.array([0, 2])
    E.deform_rest_frames(np.stack([np.eye(d) + 0.1 * rng.normal(size=(d, d)) for _ in which]), which)
    E.set_rest_scale(s)
    np.testing.assert_allclose(E.Dm_inv, expected(), rtol=1e-12, atol=1e-14)
    x = X + 0.05 * rng.normal(size=X.shape)
    E.bake(x)  # the transform is reset: the same scale again is a change
    E.set_rest_scale(s)
    np.testing.assert_array_equal(E.rest_transform, np.diag(s))
    np.testing.assert_allclose(E.Dm_inv, expected(), rtol=1e-12, atol=1e-14)
    E.set_rest_scale(1.1 * s)  # a new scale is applied
    np.testing.assert_allclose(E.Dm_inv, expected(), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(E.rest_transform, np.diag(1.1 * s))


def test_set_material_changes_the_stiffness() -> None:
    X, T = box_mesh(3)
    x = deform(X, T, "perturb", np.random.default_rng(11))
    for model in MODELS:
        E = ElasticEnergy(model, X, T, 1e4, 0.3)
        f1 = E.value(x)
        E.set_material(3e4, 0.3)
        assert E.value(x) == pytest.approx(3.0 * f1, rel=1e-12)
