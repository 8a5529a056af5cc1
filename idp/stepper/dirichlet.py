"""Dirichlet targets of one step (paper §4.3), as the Newton loop's step constraint.

For the bound vertices k ∈ B with this step's targets x̃_k:

1. ``begin``: the largest CCD- and inversion-feasible fraction α of the move of *all* bound vertices towards
   their targets is found and applied (the rest of the mesh unchanged). If α = 1 the targets are met.
2. While unmet, the penalty P(x) = κ_B/2 · Σ_k m_k ‖x_k − x̃_k‖² is part of the step energy. Whenever an iterate
   is near convergence (Newton decrement ≤ tol) and the targets are unmet, κ_B doubles (up to a cap). When a
   doubling moved the worst bound vertex less than ``min_progress`` (10 %) closer, the targets are blocked
   (the paper is silent here): κ_B stays, the step converges with the residual reported. Against elastic
   resistance alone a doubling roughly halves the residual; against contact the barrier stiffens so fast that
   it barely moves, and further doublings only crush the gaps (measured on Fig. 3 with a 1 % threshold:
   minimum distance 1e-10 with d̂ = 1e-3 and 200-iteration steps). A small gain that is larger than the one of
   the doubling before is not a block: against an elastic stiffness K far above κ_B (a stiff p-norm energy
   around a bone handle) the gain κ/(K + 2κ) is small but grows with every doubling, whereas against contact
   the barrier stiffens as the gap closes and the gains shrink. Only contact blocks: with no contact pair within
   d̂ (``in_contact`` false) κ_B keeps doubling up to its cap — a p = 10 energy stiffens like ρ⁹ around a
   point handle and its gains shrink too, yet the paper meets those targets. At the cap, still with no contact,
   the penalty becomes an augmented Lagrangian, as in the authors' code: each near-converged iterate updates a
   multiplier λ_k ← λ_k − κ_B m_k (x_k − x̃_k) (the penalty gains a linear term −λ·(x − x̃), its Hessian is
   unchanged), up to ``max_multiplier_updates`` (30) times (Fig. 19's 64K disk at p = 10: 5–15 updates met the
   targets of three steps that ended short with the penalty alone). Blocked targets are also detected away
   from convergence: when ``stall_iterations`` (30) Newton iterates whose steps CCD cut bring the worst bound
   vertex less than ``min_progress`` closer (contact keeps cutting the steps), the bound vertices are held
   where they are and the penalty is dropped, so the step converges instead of crawling to the iteration cap.
   An iterate whose cut step is ``STEP_GROWTH`` (1.5) times longer than every earlier cut step of the solve does
   not count: the pair that cuts the steps is opening. A step whose targets are those the previous step ended
   blocked on (each within ``tolerance`` of its last one), and whose feasible first move would bring no bound
   vertex ``tolerance`` closer, holds the bound vertices where they are from the start (no first move, no
   penalty; ``held_blocked`` in the report): that first move is applied unchecked and CCD lets the blocking pair
   close to ~1/8 of its gap, so a handle blocked for many steps squeezed its closest gap 8× a step down to the
   coordinates' resolution (Fig. 2's bundle: 1.7e-14 → 2.1e-15 → 4.9e-16 → 3e-16), while the re-run penalty
   only pressed it harder.
3. Once every bound vertex is within ``tolerance`` of its target, the bound vertices are put exactly on their
   targets (by a feasible move: it is checked like any other); the penalty is dropped and Newton continues to
   convergence. When that last move would collide (a free body within CCD's margin of the targets), the penalty
   stays on: Newton goes on converging, and at each near-converged iterate κ_B doubles, up to
   ``max_snap_doublings`` (8) times, while each doubling brings the worst bound vertex ``min_progress`` closer.
   A free body resists with a force of its own, so the gap it keeps depends on that force while the bound
   vertices' remaining move halves with each doubling, and the snap goes through (a repair's prescribed sphere
   pressed on the free one: 6e-5 off at the first try, snapped after Newton converged the penalty). Only when
   the doublings stop bringing them closer (the prescribed input crosses itself there) or are spent are the
   bound vertices held where they are: met within the tolerance, the residual reported.

   ``met_rule = "total_progress"`` is the authors' reading of "the targets are satisfied" (their
   ``IMPLICIT_EULER.h``, both branches): the step's bound vertices together have come ``met_progress`` (0.99) of the
   way, 1 − √(Σ_k ‖x_k − x̃_k‖² / Σ_k ‖x_k⁰ − x̃_k‖²) ≥ 0.99 with x⁰ the step's start; then the penalty is dropped and
   the bound vertices are held where they are, not put on their targets. The sum is dominated by the vertices with
   the longest moves, so vertices that resist (next to a bone handle's stiffest tets) may stay well short of theirs;
   with targets that follow the vertices (``incremental`` motions, the authors' ``Reset_Dirichlet``) the shortfall
   is never made up. Bound vertices with no move in the step (a fixed handle) are held exactly meanwhile, as
   there. The per-vertex rule above still applies first.

Bound vertices that are not optimised DOFs (a kinematic obstacle: a rigid tool) move first by the feasible
fraction at ``begin``; then each tool is one reduced Newton DOF s: its vertices at x + s·P (P = the remaining
move), pulled by the same penalty (weighted by the mean vertex mass) and pushed back by the barrier, so the tool
and the body it presses move in the same Newton step (:meth:`DirichletTargets.tool_moves`,
``StepSolver._direction_with_tools``). The tool keeps its shape, its motion is CCD-checked with everything else
(it never tunnels), and κ_B doubles, snaps and blocks as for handles. (Driving a tool's vertices one by one with
a penalty, as IPC does, lets a surface with no elasticity squash under contact: measured here, a 0.05-thick
plate pushed into a slab collapsed to zero thickness. Moving the tool only by feasible moves between Newton
solves, as idp did before, stalls as soon as the body cannot get out of the way: a plate pressing a ball onto a
floor advanced by about the barrier's equilibrium gap, ~1e-6 for d̂ = 1e-3, per Newton solve and was reported
blocked after one step; ``tools_in_newton=False`` keeps that behaviour, where a tool stops as blocked once a move
advances it less than ``kinematic_progress``.)

Targets that cannot be met (a handle pushed through an obstacle) never break injectivity: the penalty only
enters the energy, every move is still CCD- and inversion-filtered. The step then ends with κ_B at its cap and
the residual is reported (:meth:`DirichletTargets.report`).
"""

from __future__ import annotations

import math

import numpy as np

from idp.solver.constraint import FeasibleStep

#: A CCD-cut Newton step at least this much longer (as a fraction of its Newton step) than every earlier cut step of
#: the same solve does not count as stalled: the contact that cuts the steps is opening. A head pressed onto a pair
#: squeezed to ~1e-14 (Kick frame 52) advances 1e-7 of its Newton step, then each iterate a little more while the
#: barrier opens the pair, until it moves freely after ~30 iterations. Each such iterate may pass over at most a
#: factor 1.5: from a 1e-9 step at most 51 iterates go uncounted.
STEP_GROWTH = 1.5


class DirichletTargets:
    """Bound vertices, their targets for the step being solved, and the adaptive penalty κ_B (§4.3)."""

    def __init__(
        self,
        masses: np.ndarray,
        dim: int,
        *,
        tolerance: float,
        free_vertices: np.ndarray | None = None,
        kappa_initial: float = 1e4,
        max_doublings: int = 24,
        min_progress: float = 0.1,
        kinematic_progress: float | None = None,
        stall_iterations: int = 30,
        detect_blocked: bool = True,
        tools_in_newton: bool = True,
        max_multiplier_updates: int = 30,
        max_snap_doublings: int = 8,
        met_rule: str = "each_vertex",
        met_progress: float = 0.99,
    ) -> None:
        """``masses``: (n,) lumped vertex masses m_k; ``free_vertices``: (n,) bool, vertices whose DOFs Newton
        optimises (default: those with mass); ``tolerance``: distance (scene units) under which a bound vertex
        counts as on its target; ``min_progress``: a doubling (or a kinematic move) that brings the worst
        bound vertex less than this fraction closer means the targets are blocked; ``tools_in_newton``: kinematic
        bound vertices (a rigid tool) move as one reduced Newton DOF per tool, pulled by the penalty (with the
        mean vertex mass as their weight); False: only by feasible moves between Newton solves (see the module
        docstring); ``met_rule``: ``"each_vertex"`` (every bound vertex within ``tolerance``) or also
        ``"total_progress"`` (the bound vertices together ``met_progress`` of the way, the authors' rule)."""
        if not (tolerance > 0 and math.isfinite(tolerance)):
            raise ValueError(f"Dirichlet tolerance must be finite and > 0, got {tolerance!r}")
        if met_rule not in ("each_vertex", "total_progress"):
            raise ValueError(f"Dirichlet met_rule must be 'each_vertex' or 'total_progress', got {met_rule!r}")
        if not 0.0 < met_progress < 1.0:
            raise ValueError(f"Dirichlet met_progress must lie in (0, 1), got {met_progress!r}")
        self.met_rule = met_rule
        self.met_progress = float(met_progress)
        self.masses = np.asarray(masses, dtype=float)
        self.free_vertices = self.masses > 0 if free_vertices is None else np.asarray(free_vertices, dtype=bool)
        self.dim = dim
        self.tolerance = float(tolerance)
        self.kappa_initial = float(kappa_initial)
        self.kappa_max = self.kappa_initial * 2.0**max_doublings
        self.min_progress = float(min_progress)
        self.stall_iterations = int(stall_iterations)
        self.detect_blocked = bool(detect_blocked)  # False: the paper's rule alone (κ_B doubles up to its cap)
        self.kinematic_progress = float(kinematic_progress) if kinematic_progress else 0.1 * self.tolerance
        self.kappa = self.kappa_initial
        self.max_multiplier_updates = int(max_multiplier_updates)
        self.max_snap_doublings = int(max_snap_doublings)
        self.tools_in_newton = bool(tools_in_newton)
        positive = self.masses[self.masses > 0]
        self.tool_mass = float(positive.mean()) if positive.size else 1.0
        self.vertices = np.zeros(0, dtype=np.int64)
        self.targets = np.zeros((0, dim))
        self._dof = np.zeros(0, dtype=bool)  # per bound vertex: optimised (penalty), else kinematic (moves)
        self._penalised = np.zeros(0, dtype=bool)  # per bound vertex: carries the penalty
        self._weight = np.zeros(0)  # per penalised vertex: its mass in the penalty
        self._multiplier = np.zeros((0, dim))  # per penalised vertex: the augmented-Lagrangian force λ_k
        self.groups: list[tuple[str, int]] = []
        self._held = np.zeros(self.masses.size * dim, dtype=bool)
        # (bound vertices, targets) of the last step when it ended blocked, else None (:meth:`relax`, ``begin``)
        self._last_blocked: tuple[np.ndarray, np.ndarray] | None = None
        self._reset()

    def _reset(self) -> None:
        self._held[:] = False
        self._penalty_on = False
        self._met = True
        self._blocked = False
        self._last_residual: float | None = None
        self._last_gain: float | None = None
        self._best_residual: float | None = None
        self._stalled = 0
        self._widest_cut = 0.0  # the largest fraction CCD has left of a Newton step in this step
        self.feasible_fraction = 1.0
        self.doublings = 0
        self.multiplier_updates = 0
        self._multiplier = np.zeros((int(np.count_nonzero(self._penalised)), self.dim))
        self.kinematic_moves = 0
        self.frozen = False
        self.held_blocked = False  # held from the start: the targets the last step ended blocked on (``begin``)
        self._snap_residual: float | None = None  # the worst residual when κ_B was last doubled for a blocked snap
        self._snap_doublings = 0
        self._start_distance2 = 0.0  # Σ_k ‖x_k − x̃_k‖² at the step's start (the total-progress rule)
        # κ_B as of the last doubling that brought the handles min_progress closer (at first, the step's start):
        # what a step that ends blocked hands on to the next (:meth:`relax`)
        self._kappa_useful = self.kappa

    # -- set-up per step -----------------------------------------------------------------------
    def set_targets(
        self, vertices: np.ndarray, targets: np.ndarray, groups: list[tuple[str, int]] | None = None
    ) -> None:
        """The bound vertices (global ids, unique) and their targets x̃ for the next step; ``groups`` names
        consecutive runs of them (name, count) so the report gives each handle's own residual."""
        self.groups = list(groups or [])
        v = np.asarray(vertices, dtype=np.int64)
        t = np.asarray(targets, dtype=float).reshape(v.size, self.dim)
        dof = self.free_vertices[v]
        if np.any(dof & (self.masses[v] <= 0)):
            bad = int(v[np.flatnonzero(dof & (self.masses[v] <= 0))[0]])
            raise ValueError(f"bound vertex {bad} has no mass: it cannot carry a Dirichlet penalty")
        if not np.all(np.isfinite(t)):
            raise ValueError("Dirichlet targets must be finite")
        self.vertices, self.targets, self._dof = v, t, dof
        # penalised bound vertices and their weights: handles' own masses; kinematic tools' the mean mass
        self._penalised = dof | (~dof if self.tools_in_newton else np.zeros_like(dof))
        self._weight = np.where(dof, self.masses[v], self.tool_mass)[self._penalised]
        self._multiplier = np.zeros((int(np.count_nonzero(self._penalised)), self.dim))

    @property
    def active(self) -> bool:
        return self.vertices.size > 0

    def distances(self, x: np.ndarray) -> np.ndarray:
        """Distance of every bound vertex to its target."""
        return np.linalg.norm(x[self.vertices] - self.targets, axis=1) if self.active else np.zeros(0)

    def _move(self, x: np.ndarray, which: np.ndarray) -> np.ndarray:
        """The move taking the bound vertices selected by ``which`` onto their targets (others still)."""
        P = np.zeros_like(x)
        v = self.vertices[which]
        P[v] = self.targets[which] - x[v]
        return P

    # -- StepConstraint -----------------------------------------------------------------------
    def begin(self, x: np.ndarray, feasible_step: FeasibleStep) -> np.ndarray:
        self._reset()
        if not self.active:
            return x
        everything = np.ones(self.vertices.size, dtype=bool)
        P = self._move(x, everything)
        alpha = feasible_step(x, P) if np.any(P) else 1.0
        self.feasible_fraction = float(alpha)
        if alpha < 1.0 and self._still_blocked(P, alpha):
            # the targets the last step could not reach, unchanged, and still no room towards them: the first move
            # would only press the blocking pair closer (CCD keeps ~10 % of its gap, and nothing checks the energy
            # there), and the penalty only press it harder. Hold the bound vertices; the rest of the mesh relaxes.
            self._hold(met=False)
            self._blocked = True
            self.held_blocked = True
            return x
        if alpha >= 1.0:
            x = x.copy()
            x[self.vertices] = self.targets  # exactly on target (x + 1·P can differ in the last bit)
            self._hold()
            return x
        moves = P[self.vertices]
        self._start_distance2 = float(np.sum(moves**2))
        x = x + alpha * P
        self._met = False
        self._penalty_on = bool(self._penalised.any())
        if self.met_rule == "total_progress":
            # as the authors' code: bound vertices with no move this step (a fixed handle) stay exactly where
            # they are while the others are pulled, instead of being held by the penalty alone
            self._hold_vertices(self.vertices[self._dof & ~np.any(moves != 0.0, axis=1)])
        return x

    def _still_blocked(self, P: np.ndarray, alpha: float) -> bool:
        """Whether this step's targets are those the last step ended blocked on (the same bound vertices, each
        target less than ``tolerance`` from its last one: an incremental handle's targets follow the vertices a
        little) and the feasible first move would bring no bound vertex ``tolerance`` closer."""
        last = self._last_blocked
        if last is None or not self.detect_blocked:
            return False
        vertices, targets = last
        if not np.array_equal(vertices, self.vertices):
            return False
        if float(np.linalg.norm(self.targets - targets, axis=1).max(initial=0.0)) >= self.tolerance:
            return False
        return alpha * float(np.linalg.norm(P[self.vertices], axis=1).max(initial=0.0)) < self.tolerance

    def accept(self, x: np.ndarray) -> None:
        self._reset()
        self._met = bool(self.distances(x).max(initial=0.0) <= self.tolerance)
        self._blocked = not self._met

    def _hold(self, met: bool = True) -> None:
        """Hold the bound DOFs where they are and drop the penalty (on target, or frozen when stalled)."""
        self._met = met
        self._penalty_on = False
        self._hold_vertices(self.vertices[self._dof])

    def _hold_vertices(self, v: np.ndarray) -> None:
        """Mark every DOF of the vertices ``v`` as held (Newton leaves them where they are)."""
        self._held[(v[:, None] * self.dim + np.arange(self.dim)[None, :]).ravel()] = True

    @property
    def moves_obstacles(self) -> bool:
        """Whether some bound vertices are not DOFs (kinematic tools, moved by this constraint during the step)."""
        return bool(np.any(~self._dof))

    def held_dofs(self) -> np.ndarray:
        return self._held

    def penalty_value(self, x: np.ndarray) -> float:
        if not self._penalty_on:
            return 0.0
        v = self.vertices[self._penalised]
        r = x[v] - self.targets[self._penalised]
        return 0.5 * self.kappa * float(np.sum(self._weight[:, None] * r * r)) - float(np.sum(self._multiplier * r))

    def penalty_gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat gradient; entries of kinematic tool vertices too (Newton reduces them to the tools' DOFs)."""
        g = np.zeros(x.size)
        if self._penalty_on:
            v = self.vertices[self._penalised]
            r = x[v] - self.targets[self._penalised]
            g.reshape(-1, self.dim)[v] = self.kappa * self._weight[:, None] * r - self._multiplier
        return g

    def penalty_hessian_diagonal(self) -> np.ndarray:
        diag = np.zeros(self.masses.size * self.dim)
        if self._penalty_on:
            v = self.vertices[self._penalised]
            diag.reshape(-1, self.dim)[v] = self.kappa * self._weight[:, None]
        return diag

    def tool_moves(self, x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per kinematic tool still pulled by the penalty: (its bound vertices, their remaining moves (k, d)).
        Newton gives each one reduced DOF s (the tool at x + s·move: rigid, CCD-checked with the rest)."""
        kin = ~self._dof
        if not (self.tools_in_newton and self._penalty_on and kin.any()):
            return []
        groups = self.groups if sum(c for _, c in self.groups) == self.vertices.size else [("", self.vertices.size)]
        out, a = [], 0
        for _, count in groups:
            sel = np.zeros(self.vertices.size, dtype=bool)
            sel[a : a + count] = True
            a += count
            sel &= kin
            if sel.any():
                v = self.vertices[sel]
                move = self.targets[sel] - x[v]
                if np.any(move):
                    out.append((v, move))
        return out

    def after_iterate(
        self,
        x: np.ndarray,
        near_converged: bool,
        feasible_step: FeasibleStep,
        contact_limited: bool = False,
        in_contact: bool = True,
        ccd_fraction: float = 1.0,
    ) -> tuple[np.ndarray, bool]:
        if self._met:
            return x, False
        dist = self.distances(x)
        worst = float(dist.max(initial=0.0))
        if worst <= self.tolerance:
            P = self._move(x, np.ones(self.vertices.size, dtype=bool))
            if feasible_step(x, P) >= 1.0:
                x = x.copy()
                x[self.vertices] = self.targets
                self._hold()
                return x, True
            # the last bit of the move would collide. Against a free body that resists with a force of its own,
            # the gap it keeps from the bound vertices depends on that force alone, while each doubling of κ_B
            # halves the bound vertices' remaining move: a few doublings let the snap through.
            if self._penalty_on and self._snap_retry(worst, near_converged):
                return x, near_converged
            # A doubling that brought them no closer (a prescribed animation whose own parts pass through each
            # other there), or the retries spent: met within the tolerance, held where they are (further
            # doublings would only press the colliding pair together; the residual is reported)
            self._hold()
            return x, True
        if self.met_rule == "total_progress" and self._penalty_on and self._start_distance2 > 0.0:
            if 1.0 - math.sqrt(float(np.sum(dist * dist)) / self._start_distance2) >= self.met_progress:
                self._hold()  # the authors' rule: together far enough; held where they are, not snapped
                return x, True
        if self._penalty_on and not near_converged:
            # stagnation: the penalty has not brought the worst handle min_progress closer for stall_iterations
            # Newton iterates whose steps CCD cut while some pair is within d̂; freeze the handles where they are.
            # Other iterates are Newton converging towards the penalised minimum (a stiff energy such as a high
            # p-norm takes many, and its overshooting steps may be cut by CCD far from any contact): they neither
            # count as stalled nor reset the count.
            pen = float(dist[self._penalised].max())
            opening = contact_limited and ccd_fraction >= STEP_GROWTH * self._widest_cut
            if contact_limited:
                self._widest_cut = max(self._widest_cut, ccd_fraction)
            if self._best_residual is None or pen < (1.0 - self.min_progress) * self._best_residual:
                self._best_residual, self._stalled = pen, 0
            elif opening:
                pass  # CCD cuts the steps less and less: the pair that cuts them is opening (not a stall)
            elif contact_limited and in_contact and self.detect_blocked:
                self._stalled += 1
                if self._stalled >= self.stall_iterations:
                    self._hold(met=False)
                    self._blocked = True
                    self.frozen = True
                    return x, True
            return x, False
        if not near_converged or self._blocked:
            return x, False
        changed = False
        kin = ~self._dof
        if not self.tools_in_newton and kin.any() and float(dist[kin].max()) > self.tolerance:
            P = self._move(x, kin)
            alpha = feasible_step(x, P)
            advance = alpha * float(np.linalg.norm(P, axis=1).max())
            if advance >= self.kinematic_progress:
                x = x + alpha * P
                self.kinematic_moves += 1
                changed = True
        if self._penalty_on:
            pen = float(dist[self._penalised].max())
            gain = None if self._last_residual is None else 1.0 - pen / self._last_residual
            if gain is not None and gain >= self.min_progress:
                self._kappa_useful = self.kappa  # the doubling to this κ_B brought the handles closer
            if (
                in_contact
                and self.detect_blocked
                and gain is not None
                and gain < self.min_progress
                and self._last_gain is not None
                and gain <= self._last_gain
            ):
                pass  # doublings barely bring the handles closer, and less and less: blocked (stiffening crushes gaps)
            elif self.kappa < self.kappa_max:
                self._last_gain = gain
                self._last_residual = pen
                self._double_kappa()
                changed = True
            elif not in_contact and self.multiplier_updates < self.max_multiplier_updates:
                # κ_B at its cap and nothing in contact: an elastic stiffness far above κ_B (a p-norm energy around
                # a point handle) holds the handles back. Augmented Lagrangian, as the authors' code does: the
                # multiplier takes up the force the penalty lacks, λ ← λ − κ_B m (x − x̃), with κ_B unchanged
                v = self.vertices[self._penalised]
                r = x[v] - self.targets[self._penalised]
                self._multiplier -= self.kappa * self._weight[:, None] * r
                self.multiplier_updates += 1
                changed = True
        if not changed:
            self._blocked = True
        return x, changed

    def _snap_retry(self, worst: float, near_converged: bool) -> bool:
        """Whether to keep the penalty on after a blocked snap (κ_B doubled at a near-converged iterate), rather
        than hold the bound vertices within the tolerance: while retries are left, κ_B is below its cap, and
        the last doubling for a snap brought the worst bound vertex at least ``min_progress`` closer."""
        if not near_converged:
            return self._snap_doublings < self.max_snap_doublings
        if self._snap_doublings >= self.max_snap_doublings or self.kappa >= self.kappa_max:
            return False
        if self._snap_residual is not None and worst > (1.0 - self.min_progress) * self._snap_residual:
            return False
        self._snap_residual = worst
        self._snap_doublings += 1
        self._double_kappa()
        return True

    def _double_kappa(self) -> None:
        self.kappa = min(2.0 * self.kappa, self.kappa_max)
        self.doublings += 1

    @property
    def settled(self) -> bool:
        return self._met or self._blocked

    @property
    def met(self) -> bool:
        return self._met

    def relax(self) -> None:
        """Between steps: κ_B falls back towards its initial value (it is raised again where needed). After a step
        that ended blocked it first drops the doublings that did not bring the handles closer: carried on, they
        compounded from step to step while the targets stayed blocked, and each step's stiffer penalty crushed the
        gaps further (Fig. 22's vase jammed on the stems: κ_B 1.6e5 → 3.3e8 and the closest gap 3.5e-11 → 6.7e-14
        in three frames)."""
        blocked = self._blocked and not self._met
        self._last_blocked = (self.vertices.copy(), self.targets.copy()) if blocked and self.active else None
        if blocked:
            self.kappa = self._kappa_useful
        self.kappa = max(self.kappa_initial, 0.5 * self.kappa)

    def state(self) -> dict[str, np.ndarray]:
        """What the next step depends on beyond κ_B: the targets the last step ended blocked on (for a checkpoint)."""
        if self._last_blocked is None:
            return {}
        return {"blocked_vertices": self._last_blocked[0], "blocked_targets": self._last_blocked[1]}

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        if "blocked_vertices" in st and "blocked_targets" in st:
            v = np.asarray(st["blocked_vertices"], dtype=np.int64)
            t = np.asarray(st["blocked_targets"], dtype=float)
            if t.shape != (v.size, self.dim):
                raise ValueError(f"blocked_targets has shape {t.shape}, expected {(v.size, self.dim)}")
            self._last_blocked = (v, t)
        else:
            self._last_blocked = None

    def report(self, x: np.ndarray, dhat: float | None) -> dict:
        """Per-step statistics: residual (max and RMS distance to target, absolute and / d̂), κ_B, α, met."""
        dist = self.distances(x)
        mx = float(dist.max(initial=0.0))
        rms = float(np.sqrt(np.mean(dist * dist))) if dist.size else 0.0
        per_group, a = {}, 0
        for name, count in self.groups:
            per_group[name] = float(dist[a : a + count].max(initial=0.0))
            a += count
        return {
            "bound_vertices": int(self.vertices.size),
            "residual_max_per_handle": per_group,
            "met": bool(self._met),
            "blocked": bool(self._blocked),
            "frozen_after_stall": bool(self.frozen),
            "held_blocked": bool(self.held_blocked),
            "residual_max": mx,
            "residual_rms": rms,
            "residual_max_over_dhat": mx / dhat if dhat else None,
            "residual_rms_over_dhat": rms / dhat if dhat else None,
            "kappa_B": self.kappa,
            "kappa_B_doublings": self.doublings,
            "multiplier_updates": self.multiplier_updates,
            "kinematic_moves": self.kinematic_moves,
            "feasible_fraction": self.feasible_fraction,
        }
