"""Tests of idp.contact._psd_projection.project_psd against numpy's eigh-clamped projection.

Every result is checked for: agreement with V max(Λ,0) Vᵀ from np.linalg.eigh to 1e-10‖H‖_F,
PSD-ness (λ_min >= -1e-12‖H‖_F), exact symmetry, idempotence, finiteness, and that nothing
outside the leading k x k block of the (12, 12) array changes."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from idp.contact import _psd_projection as P
from idp.contact._psd_projection import WORK_ROWS, project_psd

SIZES = [3, 6, 9, 12]
SEEDS = [0, 1, 2]


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def reference(A: np.ndarray) -> np.ndarray:
    """V max(Λ,0) Vᵀ for one matrix or a stack of them (numpy / LAPACK)."""
    w, V = np.linalg.eigh(A)
    return (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)


def project_stack_paths(As: np.ndarray, work: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """project_psd on each k x k matrix of a stack (padded into a (12, 12) array with junk);
    returns the projections and the path code project_psd reported for each."""
    k = As.shape[-1]
    if work is None:
        work = np.full((WORK_ROWS, 12), np.nan)  # scratch contents must never matter
    out = np.empty_like(As)
    paths = np.empty(As.shape[0], dtype=np.int64)
    H = np.empty((12, 12))
    for n in range(As.shape[0]):
        H[:] = 7.0  # junk outside the block must stay untouched
        H[:k, :k] = As[n]
        paths[n] = project_psd(H, k, work)
        outside = H.copy()
        outside[:k, :k] = 7.0
        # never written by construction, so exact equality is the property under test
        assert np.all(outside == 7.0), "entries outside the k x k block changed"
        out[n] = H[:k, :k]
    return out, paths


def project_stack(As: np.ndarray, work: np.ndarray | None = None) -> np.ndarray:
    """project_stack_paths without the path codes."""
    return project_stack_paths(As, work)[0]


def check(As: np.ndarray, Ps: np.ndarray, rtol: float = 1e-10) -> None:
    """Ps = project_psd(As): accuracy, PSD-ness, symmetry, finiteness."""
    assert np.all(np.isfinite(Ps))
    # exact symmetry holds by construction on every CPU (each lower entry is a copy of the upper one)
    assert np.array_equal(Ps, np.swapaxes(Ps, -1, -2)), "output not exactly symmetric"
    # compare after dividing by max |A_ij| (P(A)/c = P(A/c); keeps 1e300 matrices finite)
    c = np.abs(As).max(axis=(-2, -1), keepdims=True)
    c = np.where(c > 0, c, 1.0)
    As, Ps = As / c, Ps / c
    nrm = np.linalg.norm(As, axis=(-2, -1))
    scale = np.where(nrm > 0, nrm, 1.0)
    err = np.linalg.norm(Ps - reference(As), axis=(-2, -1)) / scale
    assert err.max() <= rtol, f"max relative error {err.max():.3e}"
    lmin = np.linalg.eigvalsh(Ps)[..., 0] / scale
    assert lmin.min() >= -1e-12, f"min eigenvalue {lmin.min():.3e} ||H||"


def rand_sym(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    S = rng.standard_normal((n, k, k))
    return S + np.swapaxes(S, -1, -2)


def rand_orth(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((n, k, k)))
    return Q * np.sign(np.diagonal(R, axis1=-2, axis2=-1))[..., None, :]


def from_spectrum(Q: np.ndarray, w: np.ndarray) -> np.ndarray:
    A = (Q * w[..., None, :]) @ np.swapaxes(Q, -1, -2)
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def families(rng: np.random.Generator, k: int, n: int) -> dict[str, np.ndarray]:
    """Random test matrices, n of each family."""
    g = rng.standard_normal((n, k))
    h = rng.standard_normal((n, k))
    S = rand_sym(rng, n, k)
    outer = lambda a, b: a[:, :, None] * b[:, None, :]  # noqa: E731
    a = 10.0 ** rng.uniform(0, 8, n)[:, None, None]
    b = 10.0 ** rng.uniform(-2, 2, n)[:, None, None]
    D = 10.0 ** rng.uniform(-3, 6, (n, k))  # entries D_i S_ij D_j from ~1e-6 to ~1e12
    Q = rand_orth(rng, n, k)
    spectra = rng.choice([-2.0, -1.0, 0.0, 1.0, 3.0], (n, k))  # heavily repeated eigenvalues
    graded = rng.choice([-1.0, 1.0], (n, k)) * 10.0 ** rng.uniform(-14, 0, (n, k))
    return {
        "gradient_plus_indefinite": a * outer(g, g) + b * S,  # a g gᵀ + b S (IPC-like)
        "symmetric": S,
        "badly_scaled": D[:, :, None] * S * D[:, None, :],
        "rank1_psd": a * outer(g, g),
        "rank1_nsd": -a * outer(g, g),
        "rank2_psd": outer(g, g) + 1e3 * outer(h, h),
        "rank2_indefinite": outer(g, g) - outer(h, h),
        "pd": S @ S + 1e-3 * np.eye(k),
        "repeated_eigenvalues": from_spectrum(Q, spectra),
        "graded_spectrum": from_spectrum(Q, graded),
        "near_zero_pairs": from_spectrum(Q, np.where(spectra == 0.0, 1e-9 * graded, spectra)),
    }


# --------------------------------------------------------------------------------------
# random matrices against numpy
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("k", SIZES)
def test_matches_numpy_eigh(k, seed):
    rng = np.random.default_rng(1000 * k + seed)
    work = np.full((WORK_ROWS, 12), np.nan)
    for name, As in families(rng, k, 25).items():
        Ps = project_stack(As, work)
        try:
            check(As, Ps)
        except AssertionError as exc:  # pragma: no cover - diagnostic
            raise AssertionError(f"{name}: {exc}") from exc


@pytest.mark.parametrize("k", [1, 2, 4, 5, 7, 8, 10, 11])
def test_other_sizes(k):
    rng = np.random.default_rng(k)
    for As in families(rng, k, 10).values():
        check(As, project_stack(As))


@pytest.mark.parametrize("k", SIZES)
def test_idempotent(k):
    rng = np.random.default_rng(7 + k)
    As = np.concatenate(list(families(rng, k, 10).values()))
    P1 = project_stack(As)
    P2 = project_stack(P1)
    scale = np.maximum(np.linalg.norm(As, axis=(-2, -1)), 1e-300)
    assert (np.linalg.norm(P2 - P1, axis=(-2, -1)) / scale).max() <= 1e-12


@pytest.mark.parametrize("k", SIZES)
def test_psd_input_takes_fast_path(k):
    """PSD inputs are certified by the LDLᵀ test (PATH_FAST) and then returned untouched.

    Robustly PSD inputs (definite with a margin of 1e-3 / ~100 relative, rank one, the identity)
    must take the fast path on every CPU: their LDLᵀ pivots are positive far above TOL_PSD and
    the Schur complement left over is a few ulps, far below it.  The fast path never writes H,
    so such a block is bitwise the input (identity by construction, asserted exactly).
    Rank-two semidefinite inputs are PSD only up to the rounding of their entries; whether the
    LDLᵀ test certifies them depends on rounding (FMA contraction, target ISA), so either path
    is allowed for them, and the values are checked with a tolerance instead (below)."""
    rng = np.random.default_rng(11 + k)
    fam = families(rng, k, 20)
    g = rng.standard_normal((20, k))
    g[:, ::2] = 0.0  # normals with exact zeros
    robust = np.concatenate([fam["pd"], fam["rank1_psd"], g[:, :, None] * g[:, None, :], np.eye(k)[None]])
    for As, must_be_fast in ((robust, True), (fam["rank2_psd"], False)):
        As = 0.5 * (As + np.swapaxes(As, -1, -2))  # exactly symmetric (BLAS products need not be)
        Ps, paths = project_stack_paths(As)
        assert np.all((paths == P.PATH_FAST) | (not must_be_fast and paths == P.PATH_GENERAL)), paths
        fast = paths == P.PATH_FAST
        assert np.array_equal(Ps[fast], As[fast])  # the fast path does not write H
        # Any path: an input that is PSD up to the rounding of its entries has λ_min >= -c k u
        # max|A_ij|, so its projection moves it by O(k u)‖A‖_F, plus the kernel's own error
        # (~1e-14‖A‖_F, see the module docstring); 1e-12 leaves two orders of margin.
        nrm = np.linalg.norm(As, axis=(-2, -1))
        assert (np.linalg.norm(Ps - As, axis=(-2, -1)) / nrm).max() <= 1e-12
    Z, paths = project_stack_paths(np.zeros((1, k, k)))
    assert paths[0] == P.PATH_TRIVIAL and not Z.any()


# --------------------------------------------------------------------------------------
# special matrices
# --------------------------------------------------------------------------------------


def special_matrices(k: int) -> list[np.ndarray]:
    rng = np.random.default_rng(k)
    Q = rand_orth(rng, 1, k)[0]
    n = np.zeros(k)
    n[k // 2] = 1.0
    m = np.zeros(k)
    m[0] = 1.0
    d = np.arange(1.0, k + 1.0)
    out = [
        np.zeros((k, k)),
        np.eye(k),
        -np.eye(k),
        np.diag(d * (-1.0) ** np.arange(k)),  # diagonal, mixed signs (no reduction to do)
        np.diag(-d),
        1e12 * np.outer(n, n) - 1e-6 * np.outer(m, m),
        from_spectrum(Q, np.r_[np.full(k // 2, -1.0), np.full(k - k // 2, 1.0)]),  # ±1, repeated
        from_spectrum(Q, np.r_[-1.0, np.full(k - 1, 1e-300)]),
        from_spectrum(Q, np.r_[-1e-20, np.full(k - 1, 1.0)]),  # tiny negative eigenvalue
        np.ones((k, k)) - 2.0 * np.eye(k),
        1e-300 * rand_sym(rng, 1, k)[0],  # tiny scale
        1e300 * rand_sym(rng, 1, k)[0],  # huge scale
        np.kron(np.eye(k // 3), np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, -1.0]]))
        if k % 3 == 0
        else np.eye(k),
    ]
    A = rand_sym(rng, 1, k)[0]
    A[np.abs(A) < 1.0] = 0.0  # sparse pattern: exact zeros inside the reduction
    out.append(A)
    A = rand_sym(rng, 1, k)[0]
    A[0, 1:] = A[1:, 0] = 1e-170  # sub-underflow column for the first reflector
    out.append(A)
    return out


@pytest.mark.parametrize("k", SIZES)
def test_special_matrices(k):
    for i, A in enumerate(special_matrices(k)):
        Ps = project_stack(A[None])
        try:
            check(A[None], Ps)
        except AssertionError as exc:  # pragma: no cover - diagnostic
            raise AssertionError(f"special matrix #{i}: {exc}") from exc


@pytest.mark.parametrize("k", SIZES)
def test_nonsymmetric_input_uses_symmetric_part(k):
    rng = np.random.default_rng(3 + k)
    A = rng.standard_normal((10, k, k))
    Ps = project_stack(A)
    check(0.5 * (A + np.swapaxes(A, -1, -2)), Ps)


def test_non_finite_input_terminates_unchanged():
    work = np.empty((WORK_ROWS, 12))
    for bad in (np.nan, np.inf, -np.inf):
        H = np.eye(12)
        H[3, 5] = H[5, 3] = bad
        before = H.copy()
        assert project_psd(H, 12, work) == P.PATH_TRIVIAL
        np.testing.assert_array_equal(H, before)  # left as is by construction (NaN compares equal here)


def test_bad_arguments_raise():
    with pytest.raises(ValueError):
        project_psd(np.eye(13), 13, np.empty((WORK_ROWS, 13)))
    with pytest.raises(ValueError):
        project_psd(np.eye(12), 12, np.empty((WORK_ROWS - 1, 12)))


# --------------------------------------------------------------------------------------
# internals: the Jacobi fallback and the 3 x 3 path
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("k", SIZES)
def test_jacobi_fallback(k):
    """The fallback used when the QR iteration cap is hit (never in practice) is itself correct."""
    rng = np.random.default_rng(5 + k)
    fam = families(rng, k, 8)
    As = np.concatenate([fam["gradient_plus_indefinite"], fam["badly_scaled"], fam["repeated_eigenvalues"]])
    work = np.empty((WORK_ROWS, 12))
    Ps = np.empty_like(As)
    for n, A in enumerate(As):
        H = np.zeros((12, 12))
        H[:k, :k] = A
        P._jacobi_project(H, k, work, np.abs(A).max())
        Ps[n] = H[:k, :k]
    check(As, Ps)


def test_3x3_path_matches_general_path():
    """k = 3 has its own register-only path; compare with the general one on a 4 x 4 embedding."""
    rng = np.random.default_rng(9)
    As = np.concatenate(list(families(rng, 3, 20).values()))
    P3 = project_stack(As)
    A4 = np.zeros((As.shape[0], 4, 4))
    A4[:, :3, :3] = As
    P4 = project_stack(A4)[:, :3, :3]
    scale = np.maximum(np.linalg.norm(As, axis=(-2, -1)), 1e-300)
    assert (np.linalg.norm(P3 - P4, axis=(-2, -1)) / scale).max() <= 1e-12


# --------------------------------------------------------------------------------------
# use from compiled code (one scratch array reused for every block and size)
# --------------------------------------------------------------------------------------


@njit(cache=True)
def _project_all(Hs, ks):
    """The calling pattern of a prange chunk (kept serial here: a parallel caller only adds
    compile time; project_psd has no global state, each thread brings its own scratch)."""
    work = np.empty((WORK_ROWS, 12))
    for n in range(Hs.shape[0]):
        project_psd(Hs[n], ks[n], work)


def test_called_from_njit_loop():
    rng = np.random.default_rng(42)
    ks = rng.choice(SIZES, 400)
    Hs = np.zeros((400, 12, 12))
    for n, k in enumerate(ks):
        g = rng.standard_normal(k)
        S = rand_sym(rng, 1, k)[0]
        Hs[n, :k, :k] = 10.0 ** rng.uniform(0, 8) * np.outer(g, g) + S
    inputs = Hs.copy()
    expected = Hs.copy()
    work = np.empty((WORK_ROWS, 12))
    for n, k in enumerate(ks):
        project_psd(expected[n], k, work)
    _project_all(Hs, ks)
    # Same algorithm, but compiled inside another function (inlining may contract differently
    # into FMAs): equal up to the kernel's rounding, ~1e-14‖H‖_F (backward stable).
    nrm = np.linalg.norm(inputs, axis=(-2, -1))
    assert (np.linalg.norm(Hs - expected, axis=(-2, -1)) / nrm).max() <= 1e-12
    for n, k in enumerate(ks[:50]):
        check(inputs[n : n + 1, :k, :k], Hs[n : n + 1, :k, :k])


@pytest.mark.parametrize("k", [1, *SIZES])
def test_path_codes(k):
    """project_psd reports the path it took (used by the tests to tell the fast path apart)."""
    work = np.empty((WORK_ROWS, 12))
    for A, path in ((np.zeros((k, k)), P.PATH_TRIVIAL), (-np.eye(k), P.PATH_GENERAL)):
        assert project_psd(A.copy(), k, work) == path
    if k > 1:
        assert project_psd(np.eye(k), k, work) == P.PATH_FAST
