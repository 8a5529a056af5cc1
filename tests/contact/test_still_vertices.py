"""Pairs of vertices that do not move in a Newton step (ContactModel.hold_still, sweep_candidates(moving_only=True))
leave the barrier and CCD without changing what the step sees: the energy changes by a constant, the gradient and
the CCD step of the moving vertices are those of the whole set."""

import numpy as np
import pytest
from contact.test_compiled_barrier import SCENES

from idp.contact import ccd_filter
from idp.contact.model import ContactModel


def _scene(name, dhat=0.05):
    x, surf, nd = SCENES[name]()
    cm = ContactModel(x, surf, nd, dhat=dhat, kappa=3.0)
    # the dynamic vertices' lower part is held (with the upper box's bottom layer): pairs among them and against
    # the static part drop out, pairs with a vertex above stay
    dyn = np.arange(x.shape[0]) < nd
    lo, hi = x[dyn, 2].min(), x[dyn, 2].max()
    still = dyn & (x[:, 2] < lo + 0.55 * (hi - lo))
    return x, cm, still, nd


def _move(x, still, nd, scale, seed):
    rng = np.random.default_rng(seed)
    y = x.copy()
    moving = (np.arange(x.shape[0]) < nd) & ~still
    y[moving] += scale * rng.standard_normal((int(moving.sum()), 3))
    return y


@pytest.mark.parametrize("name", sorted(SCENES))
def test_held_pairs_change_the_barrier_by_a_constant(name):
    x, cm, still, nd = _scene(name)
    full = cm.evaluate(x)
    cm.hold_still(still)
    held = cm.evaluate(x)
    assert held.num_active < full.num_active  # the mask leaves pairs out (and keeps some, but on the static floor)
    assert held.num_active > 0 or name == "tilted_on_static"
    cm_still = still[cm.to_full]
    static = cm_still | (np.arange(cm_still.size) >= cm.num_dynamic_collision_vertices)
    fv, ee = cm._candidates(cm.surface_positions(x), None)
    assert not (static[fv[:, 1]] & static[cm._faces[fv[:, 0]]].all(axis=1)).any()  # no candidate of still vertices
    assert not (static[cm._edges[ee[:, 0]]].all(axis=1) & static[cm._edges[ee[:, 1]]].all(axis=1)).any()
    # (a kept candidate may still classify to a collision among still vertices, e.g. a face with one moving
    # vertex whose closest feature is an edge of still ones: its weight then counts the kept candidates only)
    # energy differences between states that differ only at moving vertices: the same with and without the mask
    y = _move(x, still, nd, 2e-3, 1)
    cm.hold_still(None)
    d_full = cm.value(cm.evaluate(y)) - cm.value(full)
    g_full = cm.gradient(cm.evaluate(y))
    cm.hold_still(still)
    d_held = cm.value(cm.evaluate(y)) - cm.value(held)
    g_held = cm.gradient(cm.evaluate(y))
    assert d_held == pytest.approx(d_full, rel=1e-9, abs=1e-12 * abs(cm.value(full)))
    moving = ~cm_still & (np.arange(cm_still.size) < cm.num_dynamic_collision_vertices)  # obstacles never move
    free_dofs = np.repeat(moving, 3)
    np.testing.assert_allclose(g_held[free_dofs], g_full[free_dofs], rtol=1e-9, atol=1e-12 * np.abs(g_full).max())
    cm.hold_still(None)
    assert cm.still is None and cm.evaluate(x).num_active == full.num_active


@pytest.mark.parametrize("name", sorted(SCENES))
def test_ccd_of_a_partial_move_skips_still_pairs_and_keeps_the_step(name):
    x, cm, still, nd = _scene(name)
    y = _move(x, still, nd, 0.02, 2)
    y[~still & (np.arange(x.shape[0]) < nd), 2] -= 0.6  # through the still part and the floor
    plain = cm.sweep_candidates(x, y)
    moving = cm.sweep_candidates(x, y, moving_only=True)
    assert moving[0].shape[0] + moving[1].shape[0] < plain[0].shape[0] + plain[1].shape[0]
    a_plain = cm.max_collision_free_step(x, y, plain)
    a_moving = cm.max_collision_free_step(x, y, moving)
    assert 0.0 < a_plain < 1.0  # built to collide
    assert a_moving == pytest.approx(a_plain, rel=1e-6)
    # without a given gap the narrow phase is chosen from the moving candidates' own gaps
    assert cm.max_collision_free_step(x, y, moving, None) == pytest.approx(a_plain, rel=1e-6)


def test_a_moving_obstacle_keeps_every_pair():
    x, cm, _still, nd = _scene("tilted_on_static")
    y = x.copy()
    y[nd:, 2] += 0.01  # only the static floor moves (a kinematic tool): its pairs with still vertices matter
    plain = cm.sweep_candidates(x, y)
    moving = cm.sweep_candidates(x, y, moving_only=True)
    assert plain[0].shape == moving[0].shape and plain[1].shape == moving[1].shape
    assert plain[0].shape[0] > 0


@pytest.mark.parametrize("name", sorted(SCENES))
def test_second_rescaling_is_the_same_as_a_separate_pass(name):
    x, cm, still, nd = _scene(name)
    y = _move(x, still, nd, 0.02, 3)
    v0, v1 = cm.surface_positions(x), cm.surface_positions(y)
    fv, ee = cm.sweep_candidates(x, y)
    d, m, t, t2 = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, 0.97, 0.9)
    d_a, m_a, t_a, none = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, 0.97)
    _, _, t_b, _ = ccd_filter.move_bounds(v0, v1, cm._faces, cm._edges, fv, ee, 0.9)
    assert none is None and t2 is not None
    np.testing.assert_array_equal(d, d_a)
    np.testing.assert_array_equal(m, m_a)
    np.testing.assert_array_equal(t, t_a)
    np.testing.assert_array_equal(t2, t_b)
    assert (t2 < t).any()  # the two keeps bound differently


@pytest.mark.parametrize("gap", [0.02, 0.2])
def test_any_within_dhat_without_a_collision_set(gap):
    x, surf, nd = SCENES["stacked_jittered"]()
    x = x.copy()
    upper = x[:, 2] > 1.0
    x[upper, 2] += gap
    cm = ContactModel(x, surf, nd, dhat=0.05, kappa=3.0)
    assert cm.any_within_dhat(x) == (cm.evaluate(x).num_active > 0)
    assert cm.any_within_dhat(x) == (gap < 0.05)
