"""Tests of idp.energies.inversion_filter.max_inversion_free_step."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from idp.energies.inversion_filter import _first_root, max_inversion_free_step

TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.3, 1.0]])
TRI = np.array([[0.0, 0], [1, 0], [0.3, 1.0]])


def signed_volumes(x: np.ndarray, T: np.ndarray) -> np.ndarray:
    Ds = np.transpose(x[T[:, 1:]] - x[T[:, :1]], (0, 2, 1))
    return np.linalg.det(Ds)


def grid(d: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """[0,1]^d grid split into positively oriented simplices (Kuhn subdivision)."""
    g = np.linspace(0.0, 1.0, n + 1)
    X = np.stack(np.meshgrid(*([g] * d), indexing="ij"), axis=-1).reshape(-1, d)
    idx = np.arange((n + 1) ** d).reshape((n + 1,) * d)
    cells = []
    for c in itertools.product(range(n), repeat=d):
        for perm in itertools.permutations(range(d)):
            off = np.zeros(d, int)
            s = [idx[tuple(c)]]
            for ax in perm:
                off[ax] = 1
                s.append(idx[tuple(np.add(c, off))])
            cells.append(s)
    T = np.array(cells, dtype=np.int64)
    neg = signed_volumes(X, T) < 0
    T[neg, 0], T[neg, 1] = T[neg, 1].copy(), T[neg, 0].copy()
    return X, T


@pytest.mark.parametrize("eta", [0.1, 0.0, 0.5])
def test_apex_through_base_is_clipped_at_first_root(eta: float) -> None:
    T = np.array([[0, 1, 2, 3]])
    p = np.zeros_like(TET)
    p[3] = [0.4, -0.1, -2.0]  # apex height 1 - 2s: flat at s = 0.5
    a = max_inversion_free_step(TET, p, T, eta)
    v0 = signed_volumes(TET, T)[0]
    assert a < 0.5
    assert signed_volumes(TET + a * p, T)[0] == pytest.approx(eta * v0, rel=1e-9, abs=1e-12)
    assert signed_volumes(TET + 0.5 * a * p, T)[0] > eta * v0
    assert a == pytest.approx((1 - eta) / 2, rel=1e-12)


def test_triangle_through_edge() -> None:
    T = np.array([[0, 1, 2]])
    p = np.zeros_like(TRI)
    p[2] = [0.5, -4.0]  # apex height 1 - 4s
    a = max_inversion_free_step(TRI, p.ravel(), T, 0.1)
    assert a == pytest.approx(0.9 / 4, rel=1e-12)
    assert signed_volumes(TRI + a * p, T)[0] >= 0.1 * signed_volumes(TRI, T)[0]


def test_harmless_steps_return_one() -> None:
    for X, T in (grid(3, 2), grid(2, 3)):
        assert max_inversion_free_step(X, 0.7 * X, T) == 1.0  # uniform expansion
        R = np.linalg.qr(np.random.default_rng(0).normal(size=(X.shape[1],) * 2))[0]
        assert max_inversion_free_step(X, np.zeros_like(X), T) == 1.0
        # a small rigid-ish step never gets near eta
        assert max_inversion_free_step(X, 0.01 * (X @ R.T - X), T) == 1.0


def test_first_root_picks_earliest_of_several() -> None:
    # f(s) = -(s - 0.3)(s - 0.7)(s - 2): positive at 0, roots 0.3 and 0.7 in (0, 1)
    # Tolerances: a root r moves by ~ (few u) sum |c_i| r^i / |f'(r)| under the rounding of the
    # coefficients and of the evaluation of f (with or without FMA): <= ~2e-14 for the cases here.
    c = -np.poly([0.3, 0.7, 2.0])
    assert _first_root(c[0], c[1], c[2], c[3]) == pytest.approx(0.3, abs=1e-13)
    # purely linear: 0.9 - s
    assert _first_root(0.0, 0.0, -1.0, 0.9) == pytest.approx(0.9, abs=1e-13)
    # dips close to zero (min 1e-6 at s = 0.5) but stays positive, then a root after 0.5
    c = np.poly([0.5, 0.5]) + np.array([0.0, 0.0, 1e-6])  # (s - 0.5)^2 + 1e-6
    c3 = np.polymul(c, [-1.0, 0.8])  # times (0.8 - s): root at 0.8
    assert _first_root(c3[0], c3[1], c3[2], c3[3]) == pytest.approx(0.8, abs=1e-13)
    # near-zero leading coefficient: quadratic (s-0.4)(s-0.6) with a 1e-18 cubic term
    c = np.poly([0.4, 0.6])
    assert _first_root(1e-18, c[0], c[1], c[2]) == pytest.approx(0.4, abs=1e-13)
    assert _first_root(-1e-18, c[0], c[1], c[2]) == pytest.approx(0.4, abs=1e-13)
    # never reaching zero on [0, 1]
    assert _first_root(1.0, -1.5, 0.6, 0.1) == 1.0  # f > 0 on [0,1]
    assert _first_root(0.0, 0.0, 0.0, 1.0) == 1.0


@pytest.mark.parametrize("d,seed", list(itertools.product([3, 2], range(4))))
def test_random_steps_keep_volumes_above_eta(d: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    X, T = grid(d, 3)
    X = X + 0.05 * rng.uniform(-1, 1, X.shape)
    assert np.all(signed_volumes(X, T) > 0)
    eta = 0.1
    v0 = signed_volumes(X, T)
    for scale in (0.05, 0.3, 2.0):
        p = scale * rng.normal(size=X.shape)
        a = max_inversion_free_step(X, p, T, eta)
        assert 0.0 < a <= 1.0
        s = np.linspace(0.0, a, 2001)
        vols = np.array([signed_volumes(X + si * p, T) for si in s])
        assert np.all(vols >= eta * v0 * (1 - 1e-9))
        if a < 1.0:
            # alpha is a root: some element sits at eta * v0 there
            ratio = signed_volumes(X + a * p, T) / v0
            assert ratio.min() == pytest.approx(eta, abs=1e-9)


def test_rejects_inverted_start() -> None:
    X, T = grid(2, 2)
    T = T.copy()
    T[2, [0, 1]] = T[2, [1, 0]]
    with pytest.raises(ValueError, match="element 2"):
        max_inversion_free_step(X, np.zeros_like(X), T)
