"""κ's watched distance leaves out the pairs around preserved crossings (ContactModel.kappa_distance)."""

from __future__ import annotations

import numpy as np
import pytest

from idp.contact.model import ContactModel

DHAT = 0.01


def _two_stacks(gap_near: float, gap_far: float):
    """Two stacked triangle pairs far apart: one pair ``gap_near`` apart, the other ``gap_far``."""
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    shifts = np.array([[0.0, 0.0, 0.0], [0.1, 0.1, gap_near], [10.0, 0.0, 0.0], [10.1, 0.1, gap_far]])
    x = np.vstack([tri + s for s in shifts])
    faces = np.arange(12).reshape(4, 3)
    return x, faces


@pytest.mark.parametrize("barrier", ["compiled", "ipctk"])
def test_kappa_distance_skips_exempt_vertices(barrier):
    x, faces = _two_stacks(1e-9, 0.5 * DHAT)
    cm = ContactModel(x, faces, x.shape[0], DHAT, barrier=barrier)
    ev = cm.evaluate(x)
    assert cm.min_distance(ev) == pytest.approx(1e-9, rel=1e-3)
    assert cm.kappa_distance(ev) == cm.min_distance(ev)  # nothing exempt yet
    cm.exempt_from_kappa(np.arange(6))  # the squeezed stack's vertices
    if barrier == "compiled":
        assert cm.kappa_distance(ev) == pytest.approx(0.5 * DHAT, rel=1e-6)
    else:  # the ipctk barrier keeps the global distance (documented)
        assert cm.kappa_distance(ev) == cm.min_distance(ev)
    assert cm.min_distance(ev) == pytest.approx(1e-9, rel=1e-3)  # CCD's near-contact switch still sees it


@pytest.mark.parametrize("mode", ["every_step", "once"])
def test_kappa_init_once_balances_only_the_first_step_with_contact(mode):
    """``kappa_init = "once"``: IPC's gradient balance sets κ at the first call that sees a pair within d̂ and
    never again, however strongly a later step's energy pushes into the contact; ``every_step`` raises κ then."""
    x, faces = _two_stacks(0.5 * DHAT, 0.5 * DHAT)
    cm = ContactModel(x, faces, x.shape[0], DHAT, kappa_init=mode)
    far, _ = _two_stacks(2.0 * DHAT, 2.0 * DHAT)
    cm.initialize_kappa(cm.evaluate(far), np.zeros(far.size), 1.0)  # no pair within d̂: not yet "initialised"
    assert not cm.kappa_initialized
    ev = cm.evaluate(x)
    push = np.zeros(x.size)
    push[3 * 3 + 2 :: 3][:3] = 1e-3  # the upper triangle of the first stack pressed down (energy gradient +z)
    k1 = cm.initialize_kappa(ev, push, 1.0)
    assert cm.kappa_initialized and k1 > 0.0
    k2 = cm.initialize_kappa(ev, 1e4 * push, 1.0)
    assert (k2 == k1) if mode == "once" else (k2 > k1)
    with pytest.raises(ValueError, match="kappa_init"):
        ContactModel(x, faces, x.shape[0], DHAT, kappa_init="sometimes")
