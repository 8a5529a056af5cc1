"""Conservative advancement for nearly touching pairs: never lets a gap fall below half, and does not freeze on
pairs that slide along themselves."""

import numpy as np
import pytest

from idp.contact.near_contact_ccd import conservative_step, near_pairs, pair_distances

TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _point_over_triangle(gap: float, move: np.ndarray, where=(0.25, 0.25)):
    V0 = np.vstack([[where[0], where[1], gap], TRIANGLE])
    V1 = V0.copy()
    V1[0] += move
    return V0, V1, np.array([[0, 1, 2, 3]]), np.array([True])


def _min_gap_along(V0, V1, pairs, is_pt, alpha, samples=257):
    ts = np.linspace(0.0, alpha, samples)
    return min(pair_distances(V0 + t * (V1 - V0), pairs, is_pt).min() for t in ts)


def test_sliding_at_a_tiny_gap_does_not_freeze_the_step():
    V0, V1, pairs, is_pt = _point_over_triangle(1e-6, np.array([0.01, 0.01, 0.0]))
    assert conservative_step(V0, V1, pairs, is_pt) == 1.0
    # 1e-8 below the cat's sliver: a global Lipschitz bound gave alpha = 2.5e-7 here; the advance cap still
    # allows a useful step
    V0, V1, pairs, is_pt = _point_over_triangle(1e-9, np.array([0.01, 0.01, 0.0]))
    assert conservative_step(V0, V1, pairs, is_pt) > 1e-3


@pytest.mark.parametrize("gap", [1e-6, 1e-9, 1e-12])
def test_approaching_point_keeps_half_its_gap(gap):
    V0, V1, pairs, is_pt = _point_over_triangle(gap, np.array([0.0, 0.0, -1e-3]))
    alpha = conservative_step(V0, V1, pairs, is_pt)
    assert 0.4 * gap / 1e-3 <= alpha <= 0.5 * gap / 1e-3 * (1 + 1e-6)
    assert _min_gap_along(V0, V1, pairs, is_pt, alpha) >= 0.5 * gap * (1 - 1e-6)


def test_crossing_edges_stop_before_they_touch():
    gap = 1e-9
    V0 = np.array([[-1.0, 0.0, gap], [1.0, 0.0, gap], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    V1 = V0.copy()
    V1[:2, 2] -= 2e-9 + 1e-3  # the first edge passes through the second
    pairs, is_pt = np.array([[0, 1, 2, 3]]), np.array([False])
    alpha = conservative_step(V0, V1, pairs, is_pt)
    assert 0 < alpha < gap / (2e-9 + 1e-3)
    assert _min_gap_along(V0, V1, pairs, is_pt, alpha) >= 0.5 * gap * (1 - 1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_random_moves_never_lose_more_than_half_a_gap(seed):
    rng = np.random.default_rng(seed)
    pairs, is_pt, V0s, V1s = [], [], [], []
    for k in range(40):
        base = rng.standard_normal((4, 3)) * 0.05
        pt = bool(k % 2)
        if pt:  # a point just above a random triangle
            n = np.cross(base[2] - base[1], base[3] - base[1])
            n /= np.linalg.norm(n)
            base[0] = base[1:].mean(axis=0) + 10.0 ** rng.uniform(-11, -5) * n
        else:  # two edges whose midpoints nearly meet
            d = rng.standard_normal(3)
            base[2:] += (base[:2].mean(axis=0) - base[2:].mean(axis=0)) + 10.0 ** rng.uniform(-11, -5) * d
        V0s.append(base)
        V1s.append(base + rng.standard_normal((4, 3)) * 10.0 ** rng.uniform(-5, -2))
        pairs.append(np.arange(4) + 4 * k)
        is_pt.append(pt)
    V0, V1, P, T = np.vstack(V0s), np.vstack(V1s), np.array(pairs), np.array(is_pt)
    gaps = pair_distances(V0, P, T)
    alpha = conservative_step(V0, V1, P, T)
    assert 0 < alpha <= 1
    for t in np.linspace(0.0, alpha, 65):
        assert np.all(pair_distances(V0 + t * (V1 - V0), P, T) >= 0.5 * gaps * (1 - 1e-6))


def test_near_pairs_selects_candidates_by_exact_distance():
    V = np.vstack([[0.25, 0.25, 1e-9], [0.25, 0.25, 0.5], TRIANGLE])
    faces = np.array([[2, 3, 4]])
    edges = np.array([[2, 3], [3, 4], [4, 2]])
    fv = np.array([[0, 0], [0, 1]])  # (face, vertex)
    pairs, is_pt = near_pairs(V, edges, faces, fv, np.zeros((0, 2), np.int64), 1e-6)
    assert pairs.tolist() == [[0, 2, 3, 4]] and is_pt.tolist() == [True]
