"""Conservative advancement for nearly touching pairs: never lets a gap fall below half, and does not freeze on
pairs that slide along themselves."""

import numpy as np
import pytest

from idp.contact.near_contact_ccd import conservative_step, conservative_step_2d, near_pairs, pair_distances

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


@pytest.mark.parametrize("gap", [1e-4, 1e-5])
def test_a_pair_gliding_onto_its_floor_stops_within_a_tenth_of_it(gap):
    """A point gliding down onto a triangle at a shallow angle (closing 1.5 gaps while sliding 0.5) approaches
    the gap it must keep in ever smaller advances; it stops once within ARRIVED of that floor, never below it."""
    from idp.contact.near_contact_ccd import ARRIVED

    move = np.array([0.5, 0.0, -1.5 * gap])
    V0, V1, pairs, is_pt = _point_over_triangle(gap, move, where=(0.1, 0.3))
    alpha = conservative_step(V0, V1, pairs, is_pt)  # keeps half the gap: reached at α = 1/3
    floor = 0.5 * gap
    end = pair_distances(V0 + alpha * (V1 - V0), pairs, is_pt)[0]
    assert floor * (1 - 1e-6) <= end <= ARRIVED * floor
    assert _min_gap_along(V0, V1, pairs, is_pt, alpha) >= floor * (1 - 1e-6)


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


# -- 2D: a point against a segment --------------------------------------------------------------------------------


def _point_segment_gaps(V: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Reference distances (numpy) of 2D point–segment pairs (rows: point, segment start, segment end)."""
    p, a, b = V[pairs[:, 0]], V[pairs[:, 1]], V[pairs[:, 2]]
    e = b - a
    L2 = np.einsum("ij,ij->i", e, e)
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * e), axis=1)


def test_2d_sliding_at_a_tiny_gap_does_not_freeze_the_step():
    # a Fig. 19 handle vertex sliding past the edge of its notch: at a 1e-6 gap the whole move is taken; at 1e-8 the
    # advance cap (MAX_ADVANCES) still allows a useful fraction, where a Lipschitz bound on the gap gave 3.6e-7
    move = np.array([[0.0145, 0.0], [0.0, 0.0], [0.0, 0.0]])
    V0 = np.array([[0.3, 1e-6], [0.0, 0.0], [1.0, 0.0]])
    assert conservative_step_2d(V0, V0 + move, np.array([[0, 1, 2]])) == 1.0
    V0 = np.array([[0.3, 1e-8], [0.0, 0.0], [1.0, 0.0]])
    assert conservative_step_2d(V0, V0 + move, np.array([[0, 1, 2]]), keep=0.1) > 0.1  # keep: ContactModel's


@pytest.mark.parametrize("gap", [1e-6, 1e-9, 1e-12])
def test_2d_approaching_point_keeps_its_share_of_the_gap(gap):
    V0 = np.array([[0.4, gap], [0.0, 0.0], [1.0, 0.0]])
    V1 = V0 + np.array([[0.0, -1e-3], [0.0, 0.0], [0.0, 0.0]])
    pairs = np.array([[0, 1, 2]])
    alpha = conservative_step_2d(V0, V1, pairs, keep=0.5)
    assert 0.4 * gap / 1e-3 <= alpha <= 0.5 * gap / 1e-3 * (1 + 1e-6)
    for t in np.linspace(0.0, alpha, 65):
        assert _point_segment_gaps(V0 + t * (V1 - V0), pairs)[0] >= 0.5 * gap * (1 - 1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_2d_random_moves_never_lose_more_than_the_kept_gap(seed):
    rng = np.random.default_rng(seed)
    V0s, V1s, pairs = [], [], []
    for k in range(40):
        a, b = rng.standard_normal((2, 2)) * 0.05
        e = b - a
        n = np.array([-e[1], e[0]]) / np.linalg.norm(e)
        s = rng.uniform(-0.2, 1.2)  # beside the segment or past an end
        p = a + s * e + 10.0 ** rng.uniform(-11, -5) * n
        base = np.vstack([p, a, b if k % 5 else a])  # every fifth: vertex–vertex (the segment is a point)
        V0s.append(base)
        V1s.append(base + rng.standard_normal((3, 2)) * 10.0 ** rng.uniform(-5, -2))
        pairs.append(np.arange(3) + 3 * k)
    V0, V1, P = np.vstack(V0s), np.vstack(V1s), np.array(pairs)
    gaps = _point_segment_gaps(V0, P)
    alpha = conservative_step_2d(V0, V1, P, keep=0.1)
    assert 0 < alpha <= 1
    for t in np.linspace(0.0, alpha, 65):
        assert np.all(_point_segment_gaps(V0 + t * (V1 - V0), P) >= 0.1 * gaps * (1 - 1e-6))


def test_2d_contact_model_lets_a_nearly_touching_vertex_slide():
    """A 2D vertex 1e-8 above an edge (below 1e-4·d̂: the additive CCD and the near-pair bound decide) moving along
    it: a useful part of the collision-free step is taken (the advance cap), not the ≈ 4e-7 a Lipschitz bound on the gap
    allowed."""
    from idp.contact.model import ContactModel

    V = np.array([[0.0, 0.0], [1.0, 0.0], [0.3, 1e-8], [0.3, 0.5]])
    edges = np.array([[0, 1], [2, 3]])
    model = ContactModel(V, edges, num_dynamic_vertices=4, dhat=1e-3)
    x1 = V.copy()
    x1[2:, 0] += 0.0145
    assert model.max_collision_free_step(V, x1) > 0.1
    x1 = V.copy()
    x1[2, 1] -= 1e-3  # straight down through the edge: stops with most of the gap kept
    alpha = model.max_collision_free_step(V, x1)
    assert 0.0 < alpha <= 0.9 * 1e-8 / 1e-3
