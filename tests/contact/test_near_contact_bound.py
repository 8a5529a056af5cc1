"""ContactModel.near_contact_step_bound: the pairs already closer than 1e-4·d̂ bound the CCD step of a move from
above, so the Newton loop may sweep only that part of the move.

Properties: no bound (1.0) when no pair is that close; with a pair squeezed to 1e-9 the bound is below 1 and at
least the step max_collision_free_step allows over the whole move; CCD run again on the shortened move gives a
collision-free step no longer than the bound."""

import numpy as np
import pytest
from contact.test_compiled_barrier import stacked

from idp.contact.model import ContactModel

DHAT = 0.05


def _squeezed(gap: float, seed: int):
    x, surf, nd = stacked(gap, 0.0, seed)
    cm = ContactModel(x, surf, nd, dhat=DHAT, kappa=3.0)
    upper = x[:, 2] > 1.0 + 0.5 * gap
    rng = np.random.default_rng(seed)
    y = x.copy()
    y[upper] += np.array([0.05, 0.02, -0.2]) + 0.01 * rng.standard_normal((int(upper.sum()), 3))
    return x, y, cm


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_squeezed_pair_bounds_the_step_from_above(seed):
    x, y, cm = _squeezed(1e-9, seed)
    gap = cm.min_distance(cm.evaluate(x))
    assert gap < 1e-4 * DHAT
    bound = cm.near_contact_step_bound(x, y, gap)
    assert 0.0 < bound < 1e-3  # the upper box is pushed into the lower one: the squeezed pairs close at once
    assert cm.near_contact_step_bound(x, y, None) == bound  # the gap found from the pairs within d̂ at x
    full = cm.max_collision_free_step(x, y, current_min_distance=gap)
    assert full <= bound * (1.0 + 1e-12)
    short = x + bound * (y - x)
    step = bound * cm.max_collision_free_step(x, short, current_min_distance=gap)
    assert 0.0 < step <= bound
    assert not cm.has_intersections(x + step * (y - x))


def test_no_bound_without_a_squeezed_pair():
    x, y, cm = _squeezed(1e-2, 0)
    gap = cm.min_distance(cm.evaluate(x))
    assert gap > 1e-4 * DHAT
    assert cm.near_contact_step_bound(x, y, gap) == 1.0
    assert cm.near_contact_step_bound(x, y, None) == 1.0
