"""PairSprings (sticky links), zero-length and with rest lengths: value, gradient and Hessian checked by finite
differences; compressed links projected to PSD; the contact-pattern blocks equal the Hessian restricted to the free
vertices."""

from __future__ import annotations

import numpy as np
import pytest

from idp.energies.pair_springs import PairSprings

PAIRS = np.array([[0, 3], [1, 3], [4, 6], [5, 2], [0, 6]])  # vertex 3, 6 and 0 in two links each


def _springs(dim: int = 3, seed: int = 0, rest: str = "zero") -> tuple[PairSprings, np.ndarray]:
    """``rest``: "zero" (zero-length links), "stretched" (rest lengths 0.3–0.9 of the distances) or "compressed"
    (1.2–2 times the distances: the projection clamps their transverse part)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(7, dim))
    s = PairSprings(dim, stiffness=2.5)
    r = np.linalg.norm(x[PAIRS[:, 0]] - x[PAIRS[:, 1]], axis=1)
    factor = {"zero": 0.0, "stretched": rng.uniform(0.3, 0.9, r.size), "compressed": rng.uniform(1.2, 2.0, r.size)}
    s.set_pairs(PAIRS, None if rest == "zero" else factor[rest] * r)
    return s, x


@pytest.mark.parametrize("rest", ["zero", "stretched"])
@pytest.mark.parametrize("dim", [2, 3])
def test_gradient_and_hessian_match_finite_differences(dim, rest):
    s, x = _springs(dim, rest=rest)
    g = s.gradient(x)
    H = s.hessian(x).toarray()
    eps = 1e-6
    xf = x.reshape(-1)
    for i in range(xf.size):
        e = np.zeros_like(xf)
        e[i] = eps
        fd = (s.value((xf + e).reshape(x.shape)) - s.value((xf - e).reshape(x.shape))) / (2 * eps)
        assert abs(fd - g[i]) <= 1e-6 * max(1.0, abs(g[i]))
        fdg = (s.gradient((xf + e).reshape(x.shape)) - s.gradient((xf - e).reshape(x.shape))) / (2 * eps)
        np.testing.assert_allclose(fdg, H[:, i], atol=1e-6)
    assert np.linalg.eigvalsh(H).min() >= -1e-12  # PSD as it is: no projection needed
    if rest == "zero":  # the value is the quadratic form (no constant term): E = ½ xᵀ H x
        assert s.value(x) == pytest.approx(0.5 * xf @ H @ xf, rel=1e-12)
    else:  # at the rest lengths: no force, no energy
        r = np.linalg.norm(x[PAIRS[:, 0]] - x[PAIRS[:, 1]], axis=1)
        s.set_pairs(PAIRS, r)
        assert s.value(x) == 0.0 and np.abs(s.gradient(x)).max() < 1e-12


@pytest.mark.parametrize("dim", [2, 3])
def test_compressed_links_are_projected_to_psd(dim):
    s, x = _springs(dim, rest="compressed")
    H = s.hessian(x).toarray()
    assert np.linalg.eigvalsh(H).min() >= -1e-12
    # along each link the stiffness is still k (the projection drops only the negative transverse part)
    d = x[PAIRS[0, 0]] - x[PAIRS[0, 1]]
    n = d / np.linalg.norm(d)
    K = s.link_hessians(x)[0]
    assert n @ K @ n == pytest.approx(s.stiffness, rel=1e-12)
    assert np.linalg.eigvalsh(K).min() >= -1e-12
    # and the gradient still matches finite differences of the value
    eps, xf = 1e-6, x.reshape(-1)
    for i in range(xf.size):
        e = np.zeros_like(xf)
        e[i] = eps
        fd = (s.value((xf + e).reshape(x.shape)) - s.value((xf - e).reshape(x.shape))) / (2 * eps)
        assert abs(fd - s.gradient(x)[i]) <= 1e-6 * max(1.0, abs(fd))


@pytest.mark.parametrize("rest", ["zero", "compressed"])
def test_blocks_equal_the_hessian_on_the_free_vertices(rest):
    s, x = _springs(3, rest=rest)
    v2f = np.array([0, 1, -1, 2, 3, -1, 4])  # vertices 2 and 5 pinned (e.g. an obstacle's)
    verts, blocks = s.hessian_blocks(x, v2f, width=12, scale=0.5)
    nf = 5
    H = np.zeros((3 * nf, 3 * nf))
    for vs, b in zip(verts, blocks, strict=True):
        kept = [v for v in vs if v >= 0]
        for a, va in enumerate(kept):
            for c, vc in enumerate(kept):
                H[3 * va : 3 * va + 3, 3 * vc : 3 * vc + 3] += b[3 * a : 3 * a + 3, 3 * c : 3 * c + 3]
    free = np.flatnonzero(v2f >= 0)
    dofs = (3 * free[:, None] + np.arange(3)).reshape(-1)
    np.testing.assert_allclose(H, 0.5 * s.hessian(x).toarray()[np.ix_(dofs, dofs)], atol=1e-14)
    # the link (5, 2) joins two pinned vertices: dropped
    assert verts.shape[0] == 4


def test_bad_input():
    with pytest.raises(ValueError, match="positive"):
        PairSprings(3, 0.0)
    s = PairSprings(3, 1.0)
    with pytest.raises(ValueError, match="two different vertices"):
        s.set_pairs(np.array([[1, 1]]))
    with pytest.raises(ValueError, match="rest lengths for"):
        s.set_pairs(np.array([[0, 1]]), np.array([0.1, 0.2]))
    with pytest.raises(ValueError, match="non-negative"):
        s.set_pairs(np.array([[0, 1]]), np.array([-0.1]))
    assert s.value(np.zeros((3, 3))) == 0.0 and not s.gradient(np.zeros((3, 3))).any()
