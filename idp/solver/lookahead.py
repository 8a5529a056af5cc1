"""When a Newton iteration's search matrix gets the contact look-ahead (``[solver] contact_lookahead``).

After a step that CCD cut short, the next search matrix also sees, with a small stiffness, the pairs that the cut
move would have brought within the look-ahead's reach beyond d̂ (a majorant of the exact matrix): the direction
then slows the closing pairs down instead of running into them again. Only an exact matrix's direction may end a
step's solve, so a majorant's direction within tol is followed by an exact iteration.

That can alternate without end: the majorant holds the closing pairs where they are (its direction is within tol
and barely moves anything), the exact direction, which does not see them, drives them on and is cut short again.
After ``max_futile`` such rounds the look-ahead stays off for the rest of the step's solve."""

from __future__ import annotations

import numpy as np

#: On for the next iteration after an accepted step that CCD cut below this fraction of the Newton step (and so on
#: while the cuts go on), with a barrier stiffness of this share of κ (bunny_700: shares 1, 0.1, 0.01, 0.001 gave
#: 279, 229, 208, 219 Newton iterations against 240 without; 0.01 at reach 3: 199).
LOOKAHEAD_TRIGGER = 0.5
LOOKAHEAD_STIFFNESS = 0.01

#: Rounds of "majorant within tol, then the exact direction cut short by CCD" after which the look-ahead stays off
#: in a step. Light petals sagging onto each other just outside d̂ (Fig. 22's rhododendron on its stem, 36K vertices,
#: 3 steps): 116, 43 and 14 Newton iterations with the look-ahead, 68, 20 and 6 of them majorant ones; 44, 6 and 6
#: without it; 39, 9 and 9 with this limit of 2. bunny_700 / bunny_1922 and the demo never reach it (203, 247 and
#: 508 iterations either way).
LOOKAHEAD_MAX_FUTILE = 2


class LookaheadSwitch:
    """The look-ahead's state during one step's Newton solve, one switch per body (``bodies``; 1: the whole system).

    Bodies that cannot meet (islands, :mod:`idp.solver.islands`) have separate switches, as they would alone: one
    flower whose move CCD cuts short turns the look-ahead on for its own pairs only, and one flower's futile rounds
    turn it off for that flower only. ``enabled``: the scene's reach is above 1."""

    def __init__(self, enabled: bool, bodies: int = 1, max_futile: int = LOOKAHEAD_MAX_FUTILE):
        self.enabled = enabled
        self.max_futile = max_futile
        self.on = np.zeros(bodies, dtype=bool)  # whether the next search matrix gets the look-ahead, per body
        self.futile = np.zeros(bodies, dtype=np.int64)  # exact directions cut short right after a majorant's within tol
        self._settled_majorant = np.zeros(bodies, dtype=bool)  # the last direction was a majorant's, within tol
        self._after_settled = np.zeros(bodies, dtype=bool)  # this iteration follows such a one

    @property
    def any_on(self) -> bool:
        """Whether the next search matrix gets look-ahead blocks for any body."""
        return bool(self.on.any())

    def may_end_solve(self, within_tol: bool, used: np.ndarray | bool, body_within: np.ndarray | None = None) -> bool:
        """Whether this iteration's direction, with its decrement within tol or not, may end the solve; ``used``:
        its matrix held look-ahead blocks (per body, or one value for all: a majorant's direction, the next,
        exact, iteration judges). ``body_within``: per body, whether its own part of the direction is within tol
        (default: ``within_tol`` for every body); the solve's end is judged on the whole direction."""
        used = np.broadcast_to(np.asarray(used, dtype=bool), self.on.shape)
        within = np.broadcast_to(np.asarray(within_tol if body_within is None else body_within, dtype=bool), used.shape)
        self._after_settled = self._settled_majorant
        self._settled_majorant = within & used
        self.on = self.on & ~self._settled_majorant
        return bool(within_tol) and not bool(used.any())

    def after_step(self, ccd_fraction: np.ndarray | float, used: np.ndarray | bool, allowed: bool) -> None:
        """Decide the next iteration's matrix from the accepted step (``ccd_fraction`` and ``used`` per body or one
        value for all): on after a step CCD cut below LOOKAHEAD_TRIGGER while ``allowed`` (a collision set, no
        kinematic tool moving) and not yet futile; off, whatever the cut, after a majorant's direction within tol,
        so that an exact direction judges it (kept on there, a majorant's steps that CCD cut every time never let an
        exact direction end the solve: Fig. 2's late steps, 44–99 look-ahead iterations in a row, every decrement
        within tol)."""
        cut = np.broadcast_to(np.asarray(ccd_fraction) < LOOKAHEAD_TRIGGER, self.on.shape)
        used = np.broadcast_to(np.asarray(used, dtype=bool), self.on.shape)
        self.futile += cut & self._after_settled & ~used  # the majorant said "here", the exact direction went on
        allowed_now = bool(self.enabled and allowed)
        self.on = cut & ~self._settled_majorant & (self.futile < self.max_futile) & allowed_now
