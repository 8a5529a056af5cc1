"""What the Newton loop asks of a step constraint (paper §4.3 boundary conditions, §4.5 handles).

A step constraint owns a set of bound DOFs with targets for the step being solved. The Newton loop calls it at
three fixed points and knows nothing else about it:

- :meth:`StepConstraint.begin` before the first iterate: it may move the bound vertices by a feasible step
  (``feasible_step(x, P)`` gives the largest collision- and inversion-free fraction of a move P) and decides
  which DOFs are held and whether its penalty is on;
- its penalty (value, gradient, Hessian diagonal) is part of the step energy while it is on; held DOFs get a
  zero gradient and an identity row/column in the Newton system, so they do not move;
- :meth:`StepConstraint.after_iterate` after every accepted iterate, told whether the iterate is near
  convergence: it may hold more DOFs (targets met), drop its penalty, or stiffen it. It returns True when the
  objective changed (the loop then re-evaluates it). Newton may stop only when :attr:`settled` is True.
- optionally ``tool_moves(x)``: rigid groups of non-optimised vertices (kinematic tools), each with its remaining
  move; Newton then adds one reduced DOF per tool (the tool at x + s·move) to the step's system.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

#: feasible_step(x, P) → largest α ∈ [0, 1] such that x + α·P is intersection- and inversion-free.
FeasibleStep = Callable[[np.ndarray, np.ndarray], float]


class StepConstraint(Protocol):
    def begin(self, x: np.ndarray, feasible_step: FeasibleStep) -> np.ndarray:
        """Start of a step: returns the (possibly moved) start iterate."""
        ...

    def accept(self, x: np.ndarray) -> None:
        """The step ended at ``x`` without Newton iterations (its inertia target was the exact minimiser, see
        :meth:`idp.solver.newton.StepSolver.solve`): record whether the targets are met there."""
        ...

    @property
    def moves_obstacles(self) -> bool:
        """Whether it moves vertices that are not DOFs (kinematic tools) during the step: the contact model then
        keeps every pair of held vertices, since a tool can reach them."""
        ...

    def held_dofs(self) -> np.ndarray:
        """(n·d,) bool: DOFs held at their current value during the rest of the step."""
        ...

    def penalty_value(self, x: np.ndarray) -> float: ...

    def penalty_gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·d,) gradient of the penalty (zeros when it is off)."""
        ...

    def penalty_hessian_diagonal(self) -> np.ndarray:
        """Flat (n·d,) diagonal of the penalty's Hessian (zeros when it is off)."""
        ...

    def after_iterate(
        self,
        x: np.ndarray,
        near_converged: bool,
        feasible_step: FeasibleStep,
        contact_limited: bool = False,
        in_contact: bool = True,
        ccd_fraction: float = 1.0,
    ) -> tuple[np.ndarray, bool]:
        """After an accepted iterate: (possibly snapped x, whether the objective changed); ``contact_limited``:
        the iterate's step was cut by CCD (to ``ccd_fraction`` of the Newton step); ``in_contact``: some contact
        pair is within d̂ at x."""
        ...

    @property
    def settled(self) -> bool:
        """True when Newton may stop: targets met, or the penalty has reached its cap."""
        ...
