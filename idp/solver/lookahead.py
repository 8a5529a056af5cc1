"""When a Newton iteration's search matrix gets the contact look-ahead (``[solver] contact_lookahead``).

After a step that CCD cut short, the next search matrix also sees, with a small stiffness, the pairs that the cut
move would have brought within the look-ahead's reach beyond d̂ (a majorant of the exact matrix): the direction
then slows the closing pairs down instead of running into them again. Only an exact matrix's direction may end a
step's solve, so a majorant's direction within tol is followed by an exact iteration.

That can alternate without end: the majorant holds the closing pairs where they are (its direction is within tol
and barely moves anything), the exact direction, which does not see them, drives them on and is cut short again.
After ``max_futile`` such rounds the look-ahead stays off for the rest of the step's solve."""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass
class LookaheadSwitch:
    """The look-ahead's state during one step's Newton solve. ``enabled``: the scene's reach is above 1."""

    enabled: bool
    max_futile: int = LOOKAHEAD_MAX_FUTILE
    on: bool = False  # whether the next search matrix gets the look-ahead
    futile: int = 0  # exact directions cut short right after a majorant's within tol
    _settled_majorant: bool = False  # the last iteration's direction was a majorant's, within tol
    _after_settled: bool = False  # this iteration follows such a one

    def may_end_solve(self, within_tol: bool, used: bool) -> bool:
        """Whether this iteration's direction, with its decrement within tol or not, may end the solve; ``used``:
        its matrix held look-ahead blocks (a majorant's direction: the next, exact, iteration judges)."""
        self._after_settled, self._settled_majorant = self._settled_majorant, False
        if within_tol and used:
            self.on, self._settled_majorant = False, True
            return False
        return within_tol

    def after_step(self, ccd_fraction: float, used: bool, allowed: bool) -> None:
        """Decide the next iteration's matrix from the accepted step: on after a step CCD cut below
        LOOKAHEAD_TRIGGER while ``allowed`` (a collision set, no kinematic tool moving) and not yet futile."""
        cut = ccd_fraction < LOOKAHEAD_TRIGGER
        if cut and self._after_settled and not used:
            self.futile += 1  # the majorant said "here", the exact direction went on and was cut short
        self.on = self.enabled and cut and allowed and self.futile < self.max_futile
