"""ContactModel.evaluate hands back its last collision set when asked again at exactly the same positions with the
same d̂ and pair selections (a time step starts where the previous one's line search ended), and builds a new one
whenever any of those differ."""

import numpy as np
import pytest
from contact.test_compiled_barrier import SCENES

from idp.contact.model import ContactModel


def _pairs(ev) -> set:
    """The collision set as (sorted vertex ids, kind) pairs, independent of its order."""
    cs = ev.collisions
    return {(tuple(sorted(int(v) for v in cs.verts[i] if v >= 0)), int(cs.kind[i])) for i in range(len(cs))}


def _model(name: str, dhat: float = 0.05) -> tuple[np.ndarray, ContactModel, int]:
    x, surf, nd = SCENES[name]()
    return x, ContactModel(x, surf, nd, dhat=dhat, kappa=3.0), nd


@pytest.mark.parametrize("name", sorted(SCENES))
def test_the_same_positions_give_the_same_evaluation(name):
    x, cm, _ = _model(name)
    first = cm.evaluate(x)
    assert first.num_active > 0  # the scenes are built in contact
    assert cm.evaluate(x.copy()) is first  # equal positions, another array
    fresh = _model(name)[1].evaluate(x)
    assert _pairs(fresh) == _pairs(first)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_a_line_search_trial_is_the_set_a_fresh_broad_phase_finds(name):
    """The set reused at the next step's start was built from a move's candidates: the same pairs (any order) and
    the same barrier value as a broad phase at that point."""
    x, cm, nd = _model(name)
    rng = np.random.default_rng(3)
    y = x.copy()
    y[:nd] += 4e-3 * rng.standard_normal((nd, 3))
    cand = cm.sweep_candidates(x, y)
    alpha = cm.max_collision_free_step(x, y, cand)
    assert alpha > 0.0
    xt = x + 0.5 * alpha * (y - x)
    trial = cm.evaluate(xt, cm.line_search_candidates(cand, 0.5 * alpha))
    assert cm.evaluate(xt.copy()) is trial
    fresh_model = _model(name)[1]
    fresh = fresh_model.evaluate(xt)
    assert _pairs(trial) == _pairs(fresh)
    assert cm.value(trial) == pytest.approx(fresh_model.value(fresh), rel=1e-12)


def test_anything_else_that_shapes_the_set_makes_a_new_one():
    x, cm, nd = _model("stacked_jittered")
    first = cm.evaluate(x)
    y = x.copy()
    y[0, 0] = np.nextafter(y[0, 0], np.inf)  # one coordinate, one ulp
    assert cm.evaluate(y) is not first
    assert cm.evaluate(x) is not first  # the cache holds the last evaluation only
    last = cm.evaluate(x)
    dyn = np.arange(x.shape[0]) < nd
    lo, hi = x[dyn, 2].min(), x[dyn, 2].max()
    still = dyn & (x[:, 2] < lo + 0.55 * (hi - lo))  # the lower part: its pairs among themselves leave the set
    cm.hold_still(still)
    held = cm.evaluate(x)
    assert held is not last and held.num_active < last.num_active
    cm.hold_still(still.copy())  # the same mask again: a new selection, a new set (equal to the last)
    again = cm.evaluate(x)
    assert again is not held and _pairs(again) == _pairs(held)
    cm.hold_still(None)
    cm.dhat = 0.5 * cm.dhat
    smaller = cm.evaluate(x)
    assert smaller.num_active < last.num_active
    assert _pairs(smaller) <= _pairs(last)
