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
