"""The CCD candidate filter (idp.contact.ccd_filter): its bounds are conservative, the filtered CCD gives ipctk's
step, and the trimmed line-search candidates give the same collision sets."""

import ipctk
import numpy as np
import pytest
from contact.test_compiled_barrier import SCENES

from idp.contact import ccd_filter
from idp.contact.model import ContactModel
from idp.contact.near_contact_ccd import pair_distances


def _pairs(cm, fv, ee):
    F, E = cm._faces.astype(np.int64), cm._edges.astype(np.int64)
    pt = np.column_stack([fv[:, 1], F[fv[:, 0]]]) if fv.size else np.zeros((0, 4), np.int64)
    eeids = np.column_stack([E[ee[:, 0]], E[ee[:, 1]]]) if ee.size else np.zeros((0, 4), np.int64)
    pairs = np.vstack([pt, eeids]).astype(np.int64)
    is_pt = np.concatenate([np.ones(len(pt), bool), np.zeros(len(eeids), bool)])
    return pairs, is_pt


def _moved(name, scale, seed):
    x, surf, nd = SCENES[name]()
    rng = np.random.default_rng(seed)
    y = x.copy()
    y[:nd] += scale * rng.standard_normal((nd, 3))
    y[:nd, 2] -= 3 * scale  # towards the lower box / the floor
    return x, y, surf, nd


@pytest.mark.parametrize("name", sorted(SCENES))
def test_bounds_are_conservative(name):
    """d(0) is the exact distance, M the largest relative vertex displacement, and no pair comes within
    (1 − r)·d(0) before its ``first`` fraction (checked on 65 points of the move)."""
    x, y, surf, nd = _moved(name, 0.01, 0)
    cm = ContactModel(x, surf, nd, 0.05)
    v0, v1 = cm.surface_positions(x), cm.surface_positions(y)
    fv, ee = cm.sweep_candidates(x, y)
    r = 0.9
    dist, speed, first, _ = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, r)
    pairs, is_pt = _pairs(cm, fv, ee)
    assert pairs.shape[0] > 100
    np.testing.assert_allclose(dist, pair_distances(v0, pairs, is_pt), rtol=1e-12, atol=1e-15)
    dv = v1 - v0
    split = np.where(is_pt, 1, 2)
    for i in range(0, pairs.shape[0], max(1, pairs.shape[0] // 200)):
        p = pairs[i]
        m = max(np.linalg.norm(dv[p[a]] - dv[p[b]]) for a in range(split[i]) for b in range(split[i], 4))
        assert speed[i] == pytest.approx(m, rel=1e-12, abs=1e-300)
    assert (first > 0).all() and np.isfinite(first[speed > 0]).all()
    assert np.isinf(first[speed == 0]).all()
    limit = (1.0 - r) * dist
    for t in np.linspace(0.0, 1.0, 65):
        d = pair_distances(v0 + t * dv, pairs, is_pt)
        before = first > t
        assert (d[before] >= limit[before] * (1 - 1e-9)).all()
        # and the plain bound d(t) ≥ d(0) − t·M holds for every pair
        assert (d >= dist - t * speed - 1e-12).all()


@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("min_gap", [0.0, 2e-3])
def test_box_gap_shortcut_keeps_the_ccd_order(name, min_gap):
    """With ``min_gap`` a pair whose boxes alone keep it clear of the move gets their gap as d(0): a lower bound,
    never below ``min_gap``; every pair the CCD sees (t < 1) has the same exact d(0) and t as without it, and the
    bound still holds for all pairs (the distance stays above (1 − r)·d(0) before t)."""
    x, y, surf, nd = _moved(name, 0.002, 2)
    cm = ContactModel(x, surf, nd, 0.05)
    v0, v1 = cm.surface_positions(x), cm.surface_positions(y)
    fv, ee = cm.sweep_candidates(x, y)
    r, r2 = 0.9, 0.8
    exact = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, r, r2)
    fast = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, r, r2, min_gap=min_gap)
    skipped = fast[0] != exact[0]
    assert skipped.sum() > 0.2 * skipped.size  # the shortcut is taken
    # a lower bound up to rounding (the boxes' gap along z can be the exact difference of two coordinates, one ulp
    # above the distance kernel's value for a point straight above a triangle)
    assert (fast[0] <= exact[0] * (1 + 1e-12)).all() and (fast[0][skipped] >= min_gap).all()
    np.testing.assert_array_equal(fast[1], exact[1])
    for t_fast, t_exact in ((fast[2], exact[2]), (fast[3], exact[3])):
        seen = t_exact < 1.0
        np.testing.assert_array_equal(t_fast < 1.0, seen)
        np.testing.assert_array_equal(t_fast[seen], t_exact[seen])
        assert (t_fast[skipped] >= 1.0).all()
    np.testing.assert_array_equal(fast[0][~skipped], exact[0][~skipped])
    pairs, is_pt = _pairs(cm, fv, ee)
    limit = (1.0 - r) * exact[0]
    for t in np.linspace(0.0, 1.0, 33):
        d = pair_distances(v0 + t * (v1 - v0), pairs, is_pt)
        before = fast[2] > t
        assert (d[before] >= limit[before] * (1 - 1e-9)).all()


@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("scale", [0.003, 0.01, 0.03])
def test_filtered_ccd_gives_ipctk_step(name, scale):
    x, y, surf, nd = _moved(name, scale, 1)
    cm = ContactModel(x, surf, nd, 0.05)
    v0, v1 = cm.surface_positions(x), cm.surface_positions(y)
    full = ipctk.compute_collision_free_stepsize(cm.mesh, v0, v1, 0.0, ipctk.LBVH(), cm._ccd)
    cand = cm.sweep_candidates(x, y)
    alpha = cm.max_collision_free_step(x, y, cand)
    assert alpha == pytest.approx(full, rel=1e-6)
    assert cm.max_collision_free_step(x, y) == alpha  # candidates found by the model itself
    assert not cm.has_intersections(x + alpha * (y - x))


def test_narrow_phase_stops_once_no_candidate_can_come_close():
    order = np.arange(1000)
    first = np.linspace(0.0, 0.99, 1000)
    seen = []

    def narrow(idx):
        seen.append(idx.size)
        return 0.1 if idx[0] == 0 else 1.0

    assert ccd_filter.narrow_phase_in_order(order, first, narrow) == 0.1
    assert seen == [ccd_filter.FIRST_BATCH]  # every later candidate has first ≥ 0.1 > those of the batch
    seen.clear()
    assert ccd_filter.narrow_phase_in_order(order, first, lambda idx: seen.append(idx.size) or 1.0) == 1.0
    assert sum(seen) == 1000
    # a refinement that leaves out every other candidate: the narrow phase sees only the rest
    seen.clear()
    refined = []

    def refine(idx, limit):
        refined.append(limit)
        return idx[idx % 2 == 0]

    assert ccd_filter.narrow_phase_in_order(order, first, lambda idx: seen.append(idx.size) or 1.0, refine) == 1.0
    assert sum(seen) == 500 and refined[0] == 1.0


def test_refinement_keeps_the_bound_conservative():
    """After :func:`refine`, no pair comes within (1 − r)·d(0) before its (larger) ``first``."""
    x, y, surf, nd = _moved("stacked_jittered", 0.03, 4)
    cm = ContactModel(x, surf, nd, 0.05)
    v0, v1 = cm.surface_positions(x), cm.surface_positions(y)
    fv, ee = cm.sweep_candidates(x, y)
    r = 0.97
    bounds = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, r)
    before = bounds[2].copy()
    idx = np.flatnonzero(before < 1.0)
    left = ccd_filter.refine(idx, 1.0, v0, v1, cm._faces, cm._edges, fv, ee, r, bounds)
    first = bounds[2]
    assert (first >= before).all() and (first[idx] > before[idx]).any()
    assert np.array_equal(left, idx[first[idx] < 1.0])
    pairs, is_pt = _pairs(cm, fv, ee)
    limit = (1.0 - r) * bounds[0]
    for t in np.linspace(0.0, 1.0, 129):
        d = pair_distances(v0 + t * (v1 - v0), pairs, is_pt)
        ahead = first > t
        assert (d[ahead] >= limit[ahead] * (1 - 1e-9)).all()


@pytest.mark.parametrize("name", sorted(SCENES))
def test_line_search_candidates_give_the_same_collision_sets(name):
    x, y, surf, nd = _moved(name, 0.01, 2)
    cm = ContactModel(x, surf, nd, 0.05)
    cand = cm.sweep_candidates(x, y)
    alpha = cm.max_collision_free_step(x, y, cand)
    sub = cm.line_search_candidates(cand, alpha)
    assert sub[0].shape[0] + sub[1].shape[0] <= cand[0].shape[0] + cand[1].shape[0]
    for s in (alpha, 0.5 * alpha, 0.1 * alpha, 0.0):
        z = x + s * (y - x)
        e1, e2 = cm.evaluate(z, cand), cm.evaluate(z, sub)
        for k in ("verts", "kind", "local", "eps", "weight", "sqdist"):
            np.testing.assert_array_equal(getattr(e1.collisions, k), getattr(e2.collisions, k))
    other = cm.sweep_candidates(x, y)  # not the candidates of the last CCD: returned as they are
    assert cm.line_search_candidates(other, alpha) is other


def test_non_finite_move_is_not_filtered_away():
    x, _, surf, nd = _moved("stacked_jittered", 0.01, 3)
    cm = ContactModel(x, surf, nd, 0.05)
    v0 = cm.surface_positions(x)
    v1 = v0.copy()
    v1[0, 0] = np.nan
    fv, ee = cm.sweep_candidates(x, x)
    _, _, first, _ = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, 0.8)
    pairs, _ = _pairs(cm, fv, ee)
    touched = (pairs == 0).any(axis=1)
    assert touched.any() and (first[touched] == 0.0).all()


# Two crossing edges of the beam loop in tests/stepper/test_handles.py (the move of one CCD call of its step 27),
# 1.1e-7 apart, whose relative move of 0.022 first takes them to within 2e-11 of each other at α ≈ 0.062, then
# apart; each edge closes a triangle with a third vertex 0.02 off its side.
_CROSSING = np.array(
    [
        [-0.00540823743246664, 0.5631345969988345, 0.04987107948878522],
        [0.0141480733214267, 0.5465055693606399, 0.04658645233797219],
        [0.04131547390331047, 0.5282491534262498, 0.03568727532513082],
        [-0.01307341920397079, 0.5673376763609943, 0.0541863754714549],
    ]
)
_CROSSING_MOVE = np.array(
    [
        [0.00417188448453696, -0.00344684261261363, -0.00084939367701201],
        [0.01768668264939343, -0.0100121858551474, -0.00949316091780533],
        [0.00667359860721947, -0.0014579470413012, -0.00661571171312076],
        [-0.01525121223825092, 0.00868313368373053, 0.00818187234377172],
    ]
)


def test_a_pair_far_closer_than_its_move_gets_the_step_its_exact_gaps_allow():
    """Tight Inclusion answered α = 0.049 for this pair after 5.7 s; its exact gaps fall to the kept share of
    d(0) only at α ≈ 0.062. Such a pair (gap below TIGHT_GAP_SHARE of its move) is advanced with exact
    distances: the step keeps that share along the whole move and reaches within 10 % of it."""
    from idp.contact import model

    n = np.cross(_CROSSING[1] - _CROSSING[0], _CROSSING[3] - _CROSSING[2])
    n /= np.linalg.norm(n)
    n = n if n @ (_CROSSING[:2].mean(axis=0) - _CROSSING[2:].mean(axis=0)) > 0 else -n
    x = np.vstack([_CROSSING[:2], _CROSSING[:2].mean(axis=0) + 0.02 * n, _CROSSING[2:]])
    x = np.vstack([x, _CROSSING[2:].mean(axis=0) - 0.02 * n])
    move = np.vstack([_CROSSING_MOVE[:2], _CROSSING_MOVE[:2].mean(axis=0)])
    move = np.vstack([move, _CROSSING_MOVE[2:], _CROSSING_MOVE[2:].mean(axis=0)])
    cm = ContactModel(x, np.array([[0, 1, 2], [3, 4, 5]]), 6, 1e-3)
    pair, is_pt = np.array([[0, 1, 3, 4]]), np.array([False])
    d0 = float(pair_distances(x, pair, is_pt)[0])
    assert d0 < 1e-6  # far closer than its move of 0.022
    alpha = cm.max_collision_free_step(x, x + move)
    keep = (1.0 - model.TI_CONSERVATIVE_RESCALING) * d0
    ts = np.linspace(0.0, 0.1, 4001)
    gaps = np.array([pair_distances(x + t * move, pair, is_pt)[0] for t in ts])
    reach = ts[np.argmax(gaps < keep)]  # first sample below the kept share
    arrived = ts[np.argmax(gaps < 1.1 * keep)]
    assert arrived - 1e-4 <= alpha <= reach
    assert pair_distances(x + alpha * move, pair, is_pt)[0] >= keep * (1 - 1e-9)
    assert not cm.has_intersections(x + alpha * move)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_the_step_does_not_depend_on_ipctk_threads(name):
    """ipctk's narrow phase hands the earliest time of impact found so far to the next pairs, so on several
    threads its step depended on the schedule; idp runs it on one (idp.contact.model.one_ipctk_thread) and
    leaves ipctk's thread count as it found it."""
    x, y, surf, nd = _moved(name, 0.03, 5)
    before = ipctk.get_num_threads()
    steps = []
    try:
        for threads in (2, 1, 2):
            ipctk.set_num_threads(threads)
            cm = ContactModel(x, surf, nd, 0.05)
            steps.append(cm.max_collision_free_step(x, y))
            assert ipctk.get_num_threads() == threads
    finally:
        ipctk.set_num_threads(before)
    assert steps[0] < 1.0 and steps[0] == steps[1] == steps[2]  # identical by construction: one thread each time
