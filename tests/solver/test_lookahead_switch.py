"""The contact look-ahead's switch (idp.solver.lookahead): on after CCD-cut steps, only an exact direction ends a
solve, and off for the rest of the solve once majorant and exact directions alternate futilely."""

from __future__ import annotations

from idp.solver.lookahead import LOOKAHEAD_MAX_FUTILE, LOOKAHEAD_TRIGGER, LookaheadSwitch

CUT, FREE = 0.1 * LOOKAHEAD_TRIGGER, 1.0


def test_on_while_steps_are_cut_and_off_after_a_free_step():
    sw = LookaheadSwitch(True)
    assert not sw.on
    for _ in range(10):  # a long approach: cut after cut, majorants not yet within tol (bunny-like)
        assert not sw.may_end_solve(False, used=sw.on)
        sw.after_step(CUT, used=sw.on, allowed=True)
        assert sw.on
    assert sw.futile == 0
    sw.may_end_solve(False, used=True)
    sw.after_step(FREE, used=True, allowed=True)
    assert not sw.on


def test_only_an_exact_direction_ends_the_solve():
    sw = LookaheadSwitch(True)
    sw.may_end_solve(False, used=False)
    sw.after_step(CUT, used=False, allowed=True)
    assert sw.on
    assert not sw.may_end_solve(True, used=True)  # the majorant's direction within tol: not the end
    assert not sw.on  # the next matrix is exact
    sw.after_step(0.9, used=True, allowed=True)
    assert sw.may_end_solve(True, used=False)  # the exact one within tol ends it
    assert sw.futile == 0


def test_a_majorant_within_tol_is_judged_by_an_exact_direction_even_when_its_step_was_cut():
    """A majorant's direction within tol whose own step CCD cuts: the next matrix is still exact (were it on again,
    majorants cut every time would never let the solve end: Fig. 2's late steps ran 44–99 such iterations)."""
    sw = LookaheadSwitch(True)
    sw.may_end_solve(False, used=False)
    sw.after_step(CUT, used=False, allowed=True)
    assert sw.on
    assert not sw.may_end_solve(True, used=True)  # the majorant within tol ...
    sw.after_step(CUT, used=True, allowed=True)  # ... and its step cut short
    assert not sw.on  # the next direction is exact
    assert sw.may_end_solve(True, used=False)  # and, within tol, ends the solve
    sw2 = LookaheadSwitch(True)
    sw2.may_end_solve(False, used=False)
    sw2.after_step(CUT, used=False, allowed=True)
    sw2.may_end_solve(True, used=True)
    sw2.after_step(CUT, used=True, allowed=True)
    assert not sw2.may_end_solve(False, used=False)  # the exact one is not within tol ...
    sw2.after_step(CUT, used=False, allowed=True)  # ... and cut: a futile round, the look-ahead on again
    assert sw2.futile == 1 and sw2.on


def test_futile_alternation_turns_the_look_ahead_off_for_the_solve():
    sw = LookaheadSwitch(True)
    sw.may_end_solve(False, used=False)
    sw.after_step(CUT, used=False, allowed=True)
    for round_ in range(1, LOOKAHEAD_MAX_FUTILE + 1):
        assert sw.on
        assert not sw.may_end_solve(True, used=True)  # majorant: "here"
        sw.after_step(FREE, used=True, allowed=True)  # its step barely moves anything, uncut
        assert not sw.may_end_solve(False, used=False)  # the exact direction drives the pairs on ...
        sw.after_step(CUT, used=False, allowed=True)  # ... and is cut short again
        assert sw.futile == round_
    assert not sw.on
    for _ in range(5):  # stays off for the rest of the solve, however the steps are cut
        assert not sw.may_end_solve(False, used=False)
        sw.after_step(CUT, used=False, allowed=True)
        assert not sw.on


def test_disabled_or_not_allowed_never_turns_on():
    off = LookaheadSwitch(False)
    off.after_step(CUT, used=False, allowed=True)
    assert not off.on
    tools = LookaheadSwitch(True)  # a kinematic tool moving (or no collision set)
    tools.after_step(CUT, used=False, allowed=False)
    assert not tools.on


def test_bodies_have_their_own_switches():
    """Islands (idp.solver.islands): one body's cut move turns the look-ahead on for that body alone, and its
    futile rounds turn it off for that body alone, as if each were alone."""
    sw = LookaheadSwitch(True, bodies=2)
    sw.may_end_solve(False, used=False)
    sw.after_step([CUT, FREE], used=False, allowed=True)
    assert sw.on.tolist() == [True, False]
    for round_ in range(1, LOOKAHEAD_MAX_FUTILE + 1):  # body 0 alternates futilely; body 1 is cut every time
        assert not sw.may_end_solve(False, used=[True, False], body_within=[True, False])
        sw.after_step([FREE, CUT], used=[True, False], allowed=True)
        assert not sw.may_end_solve(False, used=[False, True], body_within=[False, False])
        sw.after_step([CUT, CUT], used=[False, True], allowed=True)
        assert sw.futile.tolist() == [round_, 0]
    assert sw.on.tolist() == [False, True]


def test_a_majorant_in_any_body_defers_the_end_of_the_solve():
    sw = LookaheadSwitch(True, bodies=3)
    assert not sw.may_end_solve(True, used=[False, True, False], body_within=[True, True, True])
    assert sw.may_end_solve(True, used=[False, False, False], body_within=[True, True, True])
    assert not sw.may_end_solve(False, used=False, body_within=[True, True, True])  # the whole direction decides
