"""Projected Newton for one artificial time step (paper eq. 6), with a filtered line search.

Every accepted iterate is reached by a step that is (1) no longer than the largest inversion-free
step of every element (det-root filter), (2) collision-free by CCD, and (3) decreases the step energy
S(x) = ½‖x − x_t‖²_M + h·E_elastic(x) + κ·Σ b(d_i).  The barrier is written on its own (not ×h), as in
IPC's incremental potential; κ is IPC's adaptive stiffness.

Stopping rule: the Newton direction p at the current iterate satisfies ‖p‖ / √h ≤ tol — displacement
per unit of frame time √h, the units of the reference implementation's PNTol.  ‖p‖ is the largest DOF
(``norm = "max"``, the reference's volumetric rule) or the root mean square of the free vertices'
displacement lengths (``norm = "rms"``, the reference's shell and flow rule). The last (filtered,
energy-decreasing) step along that direction is still taken. Hitting the iteration cap is reported.

Guards: ``max_iterations`` caps the iterations of a step and ``max_seconds`` its wall-clock time; the clock is read
after each accepted iterate (so the step always ends on an intersection-free, inversion-free state, however small
the limit), and a step stopped by either is reported as not converged (``hit_iteration_cap`` / ``hit_wall_limit``).
The run loop then warns or stops as ``on_nonconvergence`` says. ``max_memory`` / ``memory_check`` install a
:class:`~idp.solver.memory.MemoryGuard` on the linear solver: the step's memory is estimated from the symbolic
analysis before the first factorisation, and a step that would not fit stops with :class:`~idp.errors.ResourceError`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from idp import interrupts
from idp._faults import kill_point
from idp.contact.near_contact_ccd import candidate_pairs
from idp.energies._stencil_term import StencilTerm
from idp.energies.term import max_step
from idp.errors import CertificateError, SolverError
from idp.solver.assembly import restrict_collision_hessian
from idp.solver.held_reduction import HeldReduction, keeps_vertex_groups
from idp.solver.islands import BodyLabels, body_labels, merge_labels
from idp.solver.linear import LinearSolver, NotPositiveDefinite
from idp.solver.lookahead import LOOKAHEAD_STIFFNESS, LOOKAHEAD_TRIGGER, LookaheadSwitch
from idp.solver.memory import MemoryGuard, step_overhead_bytes
from idp.solver.pcg import pcg_from_majorant


def _positive_scaling(diagonal: np.ndarray) -> np.ndarray:
    """|diag H| with zero, tiny or non-finite entries replaced by the median of the usable ones (or 1): the
    scaling of the gradient-descent fallback must be finite and positive (a zero entry divided by zero).

    "Tiny" is relative to the median positive entry, not to the largest: a p-norm energy's diagonal spans more
    than 12 orders of magnitude (Fig. 19's 64K disk at p = 10: a few elements at Ψ ~ 700 against thousands near
    rest), and a floor relative to the largest entry replaced most entries by the huge median of the stiff few,
    so the fallback's direction was tiny, read as converged, and the disk collapsed from step 3 (Ψ 5e14)."""
    d = np.abs(np.asarray(diagonal, dtype=float))
    positive = np.isfinite(d) & (d > 0.0)
    typical = float(np.median(d[positive])) if positive.any() else 0.0
    usable = positive & (d > 1e-12 * typical)
    floor = float(np.median(d[usable])) if usable.any() else 1.0
    return np.where(usable, d, floor)


#: An extended step may close the smallest contact gap of the full step to at most this share of it (arm10K p = 5:
#: with no such bound the last steps, with the elbow closing, missed their targets; with 1 — no pair any closer —
#: pairs that sit within d̂ from the start blocked most extensions).
EXTEND_GAP_SHARE = 0.5


def line_search_extrapolation(setting: str | float, terms) -> float:
    """The largest multiple of a full Newton step the line search tries (1: none) for the scene's setting.

    "auto" gives 2·p for p-norm energies with p > 1, 1 otherwise. Newton's step on a power law f = s^n is s/(n − 1)
    of the way to its minimum, so where a p-norm energy's large distortions dominate (n = 2p in the stretch) full
    steps creep: Fig. 19's disk at p = 10 took 40–47 iterations a step, each accepted at α = 1 with the handle
    residual unchanged. Doubling the step while the energy keeps falling (every trial filtered like any other:
    inversion filter and CCD) took it to 16–42 with the same worst distortion; at p = 1 it gains nothing. Contact
    limits it (see :meth:`StepSolver._extrapolate`)."""
    if setting != "auto":
        return float(setting)
    p = max((float(getattr(wt.term, "power", 1.0)) for wt in terms), default=1.0)
    return 2.0 * p if p > 1.0 else 1.0


def contact_lookahead_reach(setting: str | float, compiled_barrier: bool, deforming_shells: bool) -> float:
    """The contact look-ahead's reach (multiple of d̂; 0: off) for the scene's setting.

    "auto" gives 2 with the compiled barrier (the only one that builds look-ahead blocks) when every deforming
    object is a volume or a 2D mesh, 0 when a shell deforms. Measured (docs/benchmarks.md, "Contact look-ahead"):
    with a reach of 2 the bunny-in-box scenes take 18–26 % fewer Newton iterations and the demo 6 % fewer; shells
    pressing into themselves keep many pairs within 2 d̂ that slide rather than close, and the extra couplings cost
    the Fig. 12 cat more than the iterations they save (12.7 against 11.7 s)."""
    if setting != "auto":
        return float(setting)
    return 2.0 if compiled_barrier and not deforming_shells else 0.0


@dataclass
class NewtonSettings:
    tol: float = 1e-2
    norm: str = "max"  # "max" (largest DOF of p) or "rms" (root mean square of the vertex displacements)
    max_iterations: int = 200
    inversion_eta: float = 0.1
    check_every_iterate: bool = False
    min_alpha: float = 1e-12
    extrapolate: float = 1.0  # largest multiple of a full Newton step tried (doubling) while the energy falls
    # exact direction when a folded matrix says "converged" (StepSolver._exact_direction): CG tolerance
    # and cap. 1e-2 against 1e-6 at bunny_1922: 1,236 instead of 4,691 CG iterations, same fill.
    pcg_rtol: float = 1e-2
    pcg_max_iterations: int = 100
    # a folded matrix M's direction p is used only while the fold (K = exact − M) barely changes it: its Newton
    # residual ‖K·p‖ ≤ fold_distortion × ‖g‖ and M's extra stiffness along p, |pᵀK·p| ≤ fold_stiffening × pᵀM·p;
    # otherwise the pattern grows and the exact matrix is factorised (StepSolver._undistorted). Measured on every
    # folded matrix (2026-12-02): bunny_1922 in its box, ‖K·p‖/‖g‖ at most 0.27 and |pᵀK·p|/pᵀM·p at most 0.13
    # (median 0.002, 90 % below 0.006), the direction within 10 % of Newton's (median); the rose and the justicia
    # of Fig. 22 on their stems, stiffening medians 0.42 and 0.04, directions 90 % and 51 % off Newton's (median):
    # folded contact pairs whose sides must move together (petals sagging onto petals) were held nearly still,
    # and their solves took 22 and 35 Newton iterations, 9 and 16 with these checks, 9 and 7 never folding.
    fold_distortion: float = 0.5
    fold_stiffening: float = 0.02
    # in systems of at least fold_stop_min_dofs free DOFs, after fold_stop_after folds in a row have distorted their
    # directions, the rest of the step grows the pattern instead of folding (0: folds always), skipping folded
    # factorisations that would be thrown away: the stored dumplings of Fig. 21 (399,360 DOFs) landing on the pile
    # distorted 12 folds in 12 iterations, each a wasted 7-s factorisation beside a 3.5-s analysis (12 iterations:
    # 285 → 194 s, the same iterates). In small systems an analysis costs more than a factorisation and trying the
    # fold pays: Fig. 1 (≈ 30K DOFs) took 1,459 Newton iterations in 647 s folding always, 1,869 in 830 s stopping
    # after 2 (its fold and push steps are sensitive to any change of path, so part of that is chance)
    fold_stop_after: int = 2
    fold_stop_min_dofs: int = 200_000
    max_seconds: float | None = None  # wall-clock limit of one step (checked after each accepted iterate)
    max_memory: int | None = None  # bytes a step may use (on top of the memory available; None: that alone)
    memory_check: bool = True  # estimate each step's memory before factorising (see idp.solver.memory)
    # search matrices that also see contact pairs within this multiple of d̂ (0: off; StepSolver._derivatives)
    contact_lookahead: float = 0.0
    # each island of bodies that cannot meet along a move gets its own step length (idp.solver.islands)
    island_steps: bool = False


@dataclass
class NewtonResult:
    """Per-step statistics reported in stats.json."""

    iterations: int = 0
    converged: bool = False
    hit_iteration_cap: bool = False
    hit_wall_limit: bool = False  # stopped after an accepted iterate because max_seconds had passed
    line_search_failed: bool = False
    decrement: float = float("inf")
    alphas: list = field(default_factory=list)  # accepted step sizes
    ccd_alphas: list = field(default_factory=list)  # CCD bound per iteration (1 = not limiting)
    inversion_alphas: list = field(default_factory=list)
    decrements: list = field(default_factory=list)  # convergence measure per iteration (max |p| / √h)
    gradient_descent_fallbacks: int = 0
    pcg_iterations: int = 0  # CG iterations spent on exact directions after folded matrices
    exact_refactorizations: int = 0  # ... and factorisations where CG did not converge
    distorted_folds: int = 0  # folded matrices whose direction was too far from Newton's: the pattern grown instead
    lookahead_iterations: int = 0  # iterations whose search matrix saw pairs beyond d̂ (contact_lookahead)
    island_iterations: int = 0  # iterations whose islands took step lengths of their own (idp.solver.islands)
    max_islands: int = 0  # the most islands a move was split into in one iteration
    # why the last iteration's decrement, though within tol, did not end the solve ("" when it was above tol or
    # the solve converged): its direction came from a look-ahead majorant, or the step constraint changed or had
    # not settled (handles / targets still being pulled, κ_B doubled, a snap)
    unconfirmed: str = ""
    num_contacts: int = 0
    kappa: float = 0.0
    energy: float = 0.0
    elastic_energy: float = 0.0
    barrier_energy: float = 0.0
    min_distance: float = float("inf")
    exact: bool = False  # the step's minimiser was its inertia target, taken without iterations (see solve)
    # seconds: assembly (gradient, elastic + barrier Hessians, pattern), linear_solve (orderings,
    # factorisations, solves, CG), ccd (continuous collision detection), line_search (inversion filter and
    # trial energies), contact_build (broad phase and collision sets, also those of the line search),
    # check (per-iterate certificates)
    timings: dict = field(
        default_factory=lambda: {
            "assembly": 0.0,
            "linear_solve": 0.0,
            "ccd": 0.0,
            "line_search": 0.0,
            "contact_build": 0.0,
            "check": 0.0,
        }
    )


class StepSolver:
    """Solves x_{t+1} = argmin S(x) from x_t for a :class:`~idp.stepper.system.System`."""

    def __init__(self, system, settings: NewtonSettings, linear_solver: LinearSolver, certifier=None):
        self.system = system
        self.settings = settings
        self.linear = linear_solver
        self._reduction: HeldReduction | None = None  # the factorisation without held DOFs, made when first needed
        self._last_solve: Callable[[np.ndarray], np.ndarray] = linear_solver.solve  # solve of the last factor
        self.certifier = certifier
        self.iterate_checks = 0
        self._constraint = None
        self._held: np.ndarray | None = None  # free-DOF mask of DOFs held by the step constraint
        self._skip_stencils: dict[int, np.ndarray] = {}  # per term index: stencils on held or fixed DOFs only
        self._may_extend = False  # whether this iteration's full step may be extended (see _extrapolate)
        self._lookahead = LookaheadSwitch(False)  # whether the search matrix sees pairs beyond d̂ (contact_lookahead)
        self._cut_sweep = None  # sweep candidates of the last move CCD cut short (contact_lookahead)
        self._lookahead_used = np.zeros(1, dtype=bool)  # per switch: this iteration's matrix held look-ahead blocks
        self._body_ccd: np.ndarray | None = None  # per body: the CCD fraction of its island's move (split moves)
        self._row_cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (indptr, held, positions)
        self._labels: BodyLabels | None = None  # the step's bodies, when islands may take their own steps
        self._islands_now = False  # whether this iteration's move may be split into islands
        self._distorted_run = 0  # folds in a row whose directions were distorted (NewtonSettings.fold_stop_after)
        for wt in system.terms:
            if hasattr(wt.term, "inversion_eta"):
                wt.term.inversion_eta = settings.inversion_eta
        if (settings.memory_check or settings.max_memory is not None) and linear_solver.memory_guard is None:
            linear_solver.memory_guard = self._memory_guard()

    def _memory_guard(self) -> MemoryGuard:
        """The guard checking every new pattern's estimated step memory against the memory available and
        ``max_memory`` (vectors of every DOF and the collision surface's contact sets counted on top)."""
        contact, x = getattr(self.system, "contact", None), getattr(self.system, "x", None)
        primitives = 0
        if contact is not None:
            mesh = contact.mesh
            primitives = int(mesh.num_vertices) + int(mesh.edges.shape[0]) + int(mesh.faces.shape[0])
        return MemoryGuard(
            self.settings.max_memory,
            check_system=self.settings.memory_check,
            other_bytes=step_overhead_bytes(0 if x is None else x.size, primitives),
        )

    # -- energy pieces ----------------------------------------------------------------
    def _contact_eval(self, x, res: NewtonResult, candidates=None):
        if self.system.contact is None:
            return None
        t = time.perf_counter()
        ev = self.system.contact.evaluate(x, candidates)
        res.timings["contact_build"] += time.perf_counter() - t
        return ev

    def _energy(self, x, x_prev, ev) -> tuple[float, float, float]:
        s = self.system
        el = s.elastic_value(x)
        if not math.isfinite(el):
            return math.inf, el, 0.0
        b = s.contact.value(ev) if ev is not None else 0.0
        pen = self._constraint.penalty_value(x) if self._constraint is not None else 0.0
        return s.inertia.value(x, x_prev) + s.h * el + b + pen, el, b

    def _derivatives(self, x, x_prev, ev):
        s = self.system
        g = s.inertia.gradient(x, x_prev)
        diag = s.inertia.hessian_diagonal()
        c = self._constraint
        if c is not None:
            g = g + c.penalty_gradient(x)
            diag = diag + c.penalty_hessian_diagonal()
        for t in s.linear_terms:
            g += s.h * t.gradient(x)
        for t in s.pair_terms:
            g += s.h * t.gradient(x)
        asm = s.assembler
        data = asm.start_data(diag[s.dof_map.free_dofs])
        for i, wt in enumerate(s.terms):  # element Hessians streamed into the matrix, never all held
            fused = asm.fused_scatter(i) if hasattr(wt.term, "gradient_hessian_into") else None
            if fused is not None:
                ge = wt.term.gradient_hessian_into(x, fused, data, s.h * wt.weight, project=True)
            else:

                def sink(first, blocks, i=i, w=s.h * wt.weight):
                    asm.add_element_blocks(data, i, first, blocks, w)

                skip = self._skip_stencils.get(i)
                if skip is None:
                    _, ge = wt.term.value_gradient_hessian_groups(x, sink, project=True)
                else:  # stencils on held DOFs only: their gradient is zeroed and their rows dropped anyway
                    _, ge = wt.term.value_gradient_hessian_groups(x, sink, project=True, skip=skip)
            g += s.h * wt.weight * ge
        data = asm.finish_data(data)
        active = ev is not None and ev.num_active > 0
        if active:
            g[s.collision_dofs] += s.contact.gradient(ev)
        pairs = [t for t in s.pair_terms if t.pairs.shape[0]]
        if s.contact_pattern is None:
            H = sp.csr_matrix((data, asm.indices, asm.indptr), shape=asm.shape)
            if active:
                H = H + restrict_collision_hessian(s.contact.hessian(ev), s.collision_dof_to_free, s.dof_map.num_free)
            for t in pairs:
                free = s.dof_map.free_dofs
                H = H + (s.h * t.hessian(x))[free][:, free]
            return g, H
        if pairs:  # vertex-pair blocks beside the contact blocks (3D compiled barrier, checked when built)
            width = 4 * s.dim
            parts = [t.hessian_blocks(x, s.vertex_to_free, width, s.h) for t in pairs]
            if active:
                parts.insert(0, s.contact.hessian_blocks(ev, s.collision_vertex_to_free))
            block_verts = np.concatenate([p[0] for p in parts])
            blocks = np.concatenate([p[1] for p in parts])
            return g, s.contact_pattern.assemble_blocks(data, block_verts, blocks)
        if not active:
            return g, s.contact_pattern.assemble(data)
        if s.contact.compiled:
            ahead = None
            if self._lookahead.any_on:
                ahead = (self.settings.contact_lookahead, LOOKAHEAD_STIFFNESS, self._lookahead_sweep())
            stream = s.contact.hessian_block_stream(ev, s.collision_vertex_to_free, ahead)
            self._lookahead_used = self._bodies_in_lookahead(stream)
            # the elastic values on the contact layout; then the contact blocks added a range at a time (neither the
            # values on the base layout nor all the blocks are alive together with the factor: issue 16, memory)
            values = s.contact_pattern.embed(data)
            del data
            return g, s.contact_pattern.add_block_stream(values, stream)
        return g, s.contact_pattern.assemble(data, s.contact.hessian(ev), s.collision_dof_to_free)

    def _init_kappa(self, x, x_prev, ev):
        s = self.system
        g_el = s.inertia.gradient(x, x_prev) + s.h * s.elastic_gradient(x)
        s.contact.initialize_kappa(ev, np.ascontiguousarray(g_el[s.collision_dofs]), s.average_mass)

    def _check_iterate(self, x, it: int, res: NewtonResult) -> None:
        """Independent certificate of an accepted iterate (only with ``check_every_iterate``)."""
        if not self.settings.check_every_iterate or self.certifier is None:
            return
        t = time.perf_counter()
        cert = self.certifier.check(x)
        self.iterate_checks += 1
        res.timings["check"] += time.perf_counter() - t
        if not cert.ok:
            raise CertificateError(f"Newton iterate {it} failed the injectivity check: {cert.describe()}")

    def feasible_step(self, x: np.ndarray, P: np.ndarray, res: NewtonResult | None = None, ev=None) -> float:
        """Largest α ≤ 1 for which x + α·P is inversion-free (every term's ``max_step``: the det-root filter of
        barrier elastic energies) and collision-free (CCD on the shortened move)."""
        alpha, _, _, _ = self._feasible(x, P, res if res is not None else NewtonResult(), ev, ccd_only=True)
        return alpha

    def _feasible(self, x, P, res: NewtonResult, ev, ccd_only: bool = False):
        """(α, inversion α, CCD α, sweep candidates for the line search). ``ccd_only``: the move is only checked,
        no energy is evaluated along it, so CCD may skip every pair whose vertices do not move (a constraint's
        move of its bound vertices leaves all others still) and needs no collision set at x."""
        s = self.system
        t = time.perf_counter()
        alpha_inv = 1.0
        for wt in s.terms:
            alpha_inv = min(alpha_inv, max_step(wt.term, x, P))
        res.timings["line_search"] += time.perf_counter() - t
        alpha = alpha_inv
        alpha_ccd = 1.0
        cand = None
        if s.contact is not None and alpha > 0:
            if ev is None and not ccd_only:
                ev = self._contact_eval(x, res)
            gap = None if ev is None else s.contact.min_distance(ev)  # None: from the moving candidates
            t = time.perf_counter()
            # a pair already squeezed below 1e-4·d̂ may allow only a sliver of the move: sweep only that sliver
            # (ContactModel.near_contact_step_bound), then CCD checks it like any move
            short = s.contact.near_contact_step_bound(x, x + alpha * P, gap)
            res.timings["ccd"] += time.perf_counter() - t
            x_end = x + (alpha * short) * P
            t = time.perf_counter()
            cand = s.contact.sweep_candidates(x, x_end, moving_only=ccd_only)
            res.timings["contact_build"] += time.perf_counter() - t
            alpha_ccd, cand = self._ccd(x, x_end, cand, gap, ev, res, look_ahead=not ccd_only)
            alpha_ccd *= short
            alpha *= alpha_ccd
        return alpha, alpha_inv, alpha_ccd, cand

    def _ccd(self, x, x_end, cand, gap, ev, res: NewtonResult, look_ahead: bool = True):
        """(CCD α of the move x → x_end over the sweep candidates ``cand``, the candidates the line search's trials
        need). ``look_ahead``: remember the sweep for the contact look-ahead when CCD cuts the move short."""
        contact = self.system.contact
        t1 = time.perf_counter()
        alpha_ccd = contact.max_collision_free_step(x, x_end, cand, gap, ev)
        if look_ahead and alpha_ccd < LOOKAHEAD_TRIGGER and self.settings.contact_lookahead > 1.0:
            self._cut_sweep = cand  # every pair that comes within d̂ on the whole move (contact_lookahead)
        t2 = time.perf_counter()
        cand = contact.line_search_candidates(cand, alpha_ccd)
        res.timings["contact_build"] += time.perf_counter() - t2
        res.timings["ccd"] += t2 - t1
        return alpha_ccd, cand

    def _pair_bodies(self, verts: np.ndarray) -> np.ndarray:
        """Body label of each collision-mesh vertex id in ``verts`` (−1 for padding and vertices of no body)."""
        assert self._labels is not None  # only called with islands
        vlab = self._labels.vertex_label
        full = self.system.contact.to_full[np.maximum(verts, 0)]
        return np.where(verts >= 0, vlab[full], -1)

    def _lookahead_sweep(self):
        """The sweep the look-ahead sees: the last cut move's, restricted to the pairs of bodies whose switch is on
        (one switch: all of it)."""
        if self._labels is None or self._cut_sweep is None:
            return self._cut_sweep
        contact = self.system.contact
        fv, ee = self._cut_sweep
        nf = fv.shape[0]
        quads, _ = candidate_pairs(contact._edges, contact._faces, fv, ee, np.arange(nf + ee.shape[0]))
        lab = self._pair_bodies(quads)
        keep = (self._lookahead.on[np.maximum(lab, 0)] & (lab >= 0)).any(axis=1)
        return fv[keep[:nf]], ee[keep[nf:]]

    def _bodies_in_lookahead(self, stream) -> np.ndarray:
        """Per switch, whether the search matrix holds look-ahead blocks of its body's pairs."""
        if self._labels is None:
            return np.array([stream.n_ahead > 0])
        used = np.zeros(self._labels.num_labels, dtype=bool)
        if stream.n_ahead:
            lab = self._pair_bodies(stream.ahead_vertices())
            used[lab[lab >= 0]] = True
        return used

    def _bodies_within(self, p_free: np.ndarray, tol: float) -> np.ndarray | None:
        """Per body, whether its own part of the direction is within tol (None: one switch for the whole system)."""
        if self._labels is None:
            return None
        s = self.system
        n, d = s.x.shape
        size = np.zeros(n * d)
        size[s.dof_map.free_dofs] = np.abs(p_free)
        vertex_size = size.reshape(n, d)
        vlab = self._labels.vertex_label
        on_body = vlab >= 0
        if self.settings.norm == "rms":
            sq = np.bincount(vlab[on_body], (vertex_size[on_body] ** 2).sum(axis=1), self._labels.num_labels)
            count = np.bincount(vlab[on_body], minlength=self._labels.num_labels) * d
            body = np.sqrt(sq / np.maximum(count, 1))
        else:
            body = np.zeros(self._labels.num_labels)
            np.maximum.at(body, vlab[on_body], vertex_size[on_body].max(axis=1))
        return body / math.sqrt(s.h) <= tol

    def _island_feasible(self, x, P, res: NewtonResult, ev):
        """The move split into islands (:mod:`idp.solver.islands`): (α, inversion α, CCD α, line-search candidates,
        move), the trials being x + α·move. Where two or more islands move, α = 1 and ``move`` is P with each
        island's part scaled by the fraction its own inversion filter and CCD allow (the CCD α reported is the
        smallest island's); where one does, the uniform move (``move`` is P). None where the move is not split
        (fewer than two bodies move, or a pair is nearly touching): :meth:`_feasible` then."""
        s, labels = self.system, self._labels
        if labels is None:
            return None
        contact = s.contact
        vlab = labels.vertex_label
        moving = np.any(P != 0.0, axis=1) & (vlab >= 0)
        if np.unique(vlab[moving]).size < 2:
            return None
        t = time.perf_counter()
        a = np.ones(labels.num_labels)  # each body's inversion filter
        alpha_inv = 1.0
        for i, wt in enumerate(s.terms):
            ai = max_step(wt.term, x, P)
            if ai < 1.0:
                a[labels.term_labels[i]] = np.minimum(a[labels.term_labels[i]], ai)
                alpha_inv = min(alpha_inv, ai)
        res.timings["line_search"] += time.perf_counter() - t
        if not alpha_inv > 0.0:
            return None
        if ev is None:
            ev = self._contact_eval(x, res)
        gap = contact.min_distance(ev)
        body_move = np.where(vlab >= 0, a[np.maximum(vlab, 0)], 0.0)[:, None] * P
        t = time.perf_counter()
        short = contact.near_contact_step_bound(x, x + body_move, gap)
        res.timings["ccd"] += time.perf_counter() - t
        if short < 1.0:  # a pair nearly touching: the uniform path shortens the whole move first
            return None
        t = time.perf_counter()
        cand = contact.sweep_candidates(x, x + body_move)  # every pair each body's filtered move can bring near
        fv, ee = cand
        nf = fv.shape[0]
        quads, _ = candidate_pairs(contact._edges, contact._faces, fv, ee, np.arange(nf + ee.shape[0]))
        verts = contact.to_full[quads]
        pair_labels = np.where(moving[verts], vlab[verts], -1)
        num_islands, island_of_label = merge_labels(labels.num_labels, pair_labels)
        v_island = np.where(vlab >= 0, island_of_label[np.maximum(vlab, 0)], -1)
        v_island[~moving] = -1  # vertices the move leaves where they are belong to no island's move
        islands = np.unique(v_island[v_island >= 0])
        res.timings["contact_build"] += time.perf_counter() - t
        if islands.size < 2:  # one island: the uniform move, over these candidates (a superset of its own)
            alpha_ccd, cand = self._ccd(x, x + alpha_inv * P, cand, gap, ev, res)
            return alpha_inv * alpha_ccd, alpha_inv, alpha_ccd, cand, P
        island_alpha = np.ones(num_islands)
        np.minimum.at(island_alpha, island_of_label, a)
        has = pair_labels >= 0
        first = pair_labels[np.arange(pair_labels.shape[0]), np.argmax(has, axis=1)]
        pair_island = np.where(has.any(axis=1), island_of_label[np.maximum(first, 0)], -1)
        still = pair_island < 0  # pairs no move changes: their barrier terms enter every trial unchanged
        keep_fv, keep_ee = [fv[still[:nf]]], [ee[still[nf:]]]
        alpha_ccd = 1.0
        island_ccd = np.ones(num_islands)  # islands the move leaves still are not cut
        for c in islands:
            x_end = x + np.where((v_island == c)[:, None], island_alpha[c] * P, 0.0)
            sel = pair_island == c
            ac, (f_c, e_c) = self._ccd(x, x_end, (fv[sel[:nf]], ee[sel[nf:]]), gap, ev, res, look_ahead=False)
            keep_fv.append(f_c)
            keep_ee.append(e_c)
            island_alpha[c] *= ac
            island_ccd[c] = ac
            alpha_ccd = min(alpha_ccd, ac)
        if alpha_ccd < LOOKAHEAD_TRIGGER and self.settings.contact_lookahead > 1.0:
            self._cut_sweep = cand
        self._body_ccd = island_ccd[island_of_label]  # per body, for the look-ahead's switches
        res.max_islands = max(res.max_islands, int(islands.size))
        scale = np.where(v_island >= 0, island_alpha[np.maximum(v_island, 0)], 0.0)
        line_cand = (np.concatenate(keep_fv), np.concatenate(keep_ee))
        return 1.0, alpha_inv, alpha_ccd, line_cand, scale[:, None] * P

    def _closest(self, ev) -> float:
        """Distance of the closest pair within d̂ of a contact evaluation (inf: none, or no contact model)."""
        if ev is None or ev.num_active == 0:
            return math.inf
        return float(self.system.contact.min_distance(ev))

    def _measure(self, p_free: np.ndarray) -> float:
        """Size of a Newton direction for the stopping rule (see the module docstring)."""
        if self.settings.norm == "rms":
            d = self.system.dim
            return float(np.sqrt(np.dot(p_free, p_free) * d / max(p_free.size, 1)))
        return float(np.abs(p_free).max(initial=0.0))

    def _filtered_step(self, x, P, x_prev, energy, ev, res):
        """Largest step along P that is inversion-free (det-root filter) and collision-free (CCD), then
        halved until the step energy does not increase (plain decrease, as the reference); a full step is then
        extended while that pays (``settings.extrapolate``, :meth:`_extrapolate`). Where bodies that cannot meet
        move, each island's part of P is first cut by its own filters (:meth:`_island_feasible`) and the halving
        applies to that move; where it finds no decrease, the uniform move is searched as without islands."""
        cfg = self.settings
        self._body_ccd = None  # a uniform move: every body's CCD fraction is the move's
        split = self._island_feasible(x, P, res, ev) if self._islands_now else None
        if split is None:
            alpha, alpha_inv, alpha_ccd, cand = self._feasible(x, P, res, ev)
            move = P
        else:
            alpha, alpha_inv, alpha_ccd, cand, move = split
        # what the step α reports for island moves: the share of P the longest island's trial takes
        share = 1.0 if move is P else float(np.abs(move).max() / max(float(np.abs(P).max()), 1e-300))
        while alpha > cfg.min_alpha:
            xt = x + alpha * move
            evt = self._contact_eval(xt, res, cand) if ev is not None else None
            t = time.perf_counter()
            et, elt, bt = self._energy(xt, x_prev, evt)
            res.timings["line_search"] += time.perf_counter() - t
            if et <= energy:
                if alpha == 1.0 and move is P and self._may_extend and not any(a < 1.0 for a in res.ccd_alphas):
                    alpha, trial = self._extrapolate(x, P, x_prev, ev, (xt, evt, et, elt, bt), res)
                    return True, alpha, alpha_inv, alpha_ccd, trial
                if move is not P:
                    res.island_iterations += 1
                return True, alpha * share, alpha_inv, alpha_ccd, (xt, evt, et, elt, bt)
            alpha *= 0.5
        if move is not P:  # no decrease along the islands' move: the uniform move, as without islands
            self._islands_now = False
            try:
                return self._filtered_step(x, P, x_prev, energy, ev, res)
            finally:
                self._islands_now = True
        return False, 0.0, alpha_inv, alpha_ccd, None

    def _extrapolate(self, x, P, x_prev, ev, trial, res):
        """After an accepted full step ``trial`` = (x + P, its contact evaluation, energies): double the step
        while the whole longer move x → x + αP is feasible (inversion filter and CCD, as any step), lowers the
        step energy further and keeps every pair at least ``EXTEND_GAP_SHARE`` of the closest gap the full step
        left, up to ``settings.extrapolate``; returns (α, the trial taken). Called only while no earlier iteration
        of the step was cut by CCD (once contact limits the steps, longer ones do not pay: arm10K p = 5, steps
        94–100 as the elbow closes, extended throughout: 189 of 200 iterations extended in step 94, capped short of
        its targets; 5 such steps against 2 without extension) and never when kinematic tools move with the step
        (a longer step would carry them past their targets)."""
        cfg = self.settings
        floor = self._closest(trial[1])
        alpha = 1.0
        while 2.0 * alpha <= cfg.extrapolate:
            a2 = 2.0 * alpha
            f, _, _, cand = self._feasible(x, a2 * P, res, ev)
            if f < 1.0:
                break
            xt = x + a2 * P
            evt = self._contact_eval(xt, res, cand) if trial[1] is not None else None
            t = time.perf_counter()
            et, elt, bt = self._energy(xt, x_prev, evt)
            res.timings["line_search"] += time.perf_counter() - t
            if not et < trial[2] or self._closest(evt) < EXTEND_GAP_SHARE * floor:
                break
            alpha, trial = a2, (xt, evt, et, elt, bt)
        return alpha, trial

    def _hold(self, H: sp.csr_matrix) -> sp.csr_matrix:
        """Held DOFs (targets met, fixed handles): zero their rows and columns except the diagonal, so the
        Newton direction is exactly 0 there (with their gradient entries zeroed) and the pattern is kept.

        The positions to zero are found once per (pattern, held set) and reused: the held set changes only
        when targets are met, so an iteration costs one scatter of zeros."""
        held = self._held
        if held is None:
            return H
        cache = self._row_cache
        if (
            cache is None
            or cache[0].shape != H.indptr.shape
            or not np.array_equal(cache[0], H.indptr)
            or not np.array_equal(cache[1], held)
        ):
            rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
            cols = H.indices
            positions = np.flatnonzero((held[rows] | held[cols]) & (rows != cols))
            cache = self._row_cache = (H.indptr.copy(), held.copy(), positions)
        H.data[cache[2]] = 0.0
        return H

    def _factorize(self, H) -> Callable[[np.ndarray], np.ndarray]:
        """Factorise ``H`` (held rows and columns zeroed by :meth:`_hold`) and return the solve of that factor: on
        the DOFs not held alone when the held DOFs are whole vertices (:mod:`idp.solver.held_reduction`; the held
        zeros would otherwise be factorised as entries), else on ``H`` as it stands."""
        held = self._held
        if (
            held is not None
            and H.format == "csr"
            and H.has_canonical_format
            and keeps_vertex_groups(held, self.linear.dofs_per_node)
        ):
            if self._reduction is None:
                self._reduction = HeldReduction(self.linear.sibling())
            self._last_solve = self._reduction.solve  # (set first: after a failed factorisation its solve refuses)
            self._reduction.factorize(H, held)
        else:
            self._last_solve = self.linear.solve
            self.linear.factorize(H)
        return self._last_solve

    def _direction(self, H, g: np.ndarray, res: NewtonResult) -> np.ndarray:
        """Newton direction −H⁻¹g on the free DOFs (diagonally scaled gradient if H is not PD)."""
        t = time.perf_counter()
        try:
            p_free = -self._factorize(H)(g)
            if not np.all(np.isfinite(p_free)):
                raise NotPositiveDefinite("non-finite Newton direction")
        except NotPositiveDefinite:
            res.gradient_descent_fallbacks += 1
            p_free = -g / _positive_scaling(H.diagonal())
        res.timings["linear_solve"] += time.perf_counter() - t
        return p_free

    def _direction_with_tools(
        self, H, g: np.ndarray, g_full: np.ndarray, ev, tools: list, res: NewtonResult
    ) -> tuple[np.ndarray, np.ndarray]:
        """Newton direction when kinematic tools take part (§4.3 for rigid obstacles driven towards targets).

        Each tool k contributes one reduced DOF s_k: its vertices move along their remaining moves P_k
        (x_k + s_k·P_k), so the tool stays rigid and its motion and the body's response are one Newton step,
        instead of the tool creeping by CCD-bounded moves while the body is frozen. The system is H bordered by
        the tools' columns: [[H, Cᵀ], [C, D]] with C = P_kᵀ·(contact Hessian between tool and free DOFs) and
        D = P_kᵀ·(contact + penalty Hessian of the tool)·P_k, solved with H's factor (one extra solve per tool)
        and the m×m Schur complement. Returns (free-DOF direction, per-tool s_k)."""
        s = self.system
        m = len(tools)
        nd = g_full.size
        rows = np.concatenate([(v[:, None] * s.dim + np.arange(s.dim)[None, :]).ravel() for v, _ in tools])
        cols = np.concatenate([np.full(v.size * s.dim, k) for k, (v, _) in enumerate(tools)])
        vals = np.concatenate([P.ravel() for _, P in tools])
        V = sp.csr_matrix((vals, (rows, cols)), shape=(nd, m))
        g_s = V.T @ g_full
        pen_diag = self._constraint.penalty_hessian_diagonal() if self._constraint is not None else np.zeros(nd)
        D = (V.T @ sp.diags(pen_diag) @ V).toarray()
        Ct = np.zeros((g.size, m))
        if ev is not None and ev.num_active > 0:
            Vc = V[s.collision_dofs]
            HV = s.contact.hessian(ev) @ Vc
            D += (Vc.T @ HV).toarray()
            HV = np.asarray(HV.todense()) if sp.issparse(HV) else np.asarray(HV)
            to_free = s.collision_dof_to_free
            kept = to_free >= 0
            np.add.at(Ct, to_free[kept], HV[kept])
            if self._held is not None:
                Ct[self._held] = 0.0
        t = time.perf_counter()
        try:
            solve = self._factorize(H)
            p0 = -solve(g)
            if self._fold_distorts(p0, g):  # the body's direction as without tools (_undistorted)
                before = res.timings["assembly"]
                H = self._unfolded_matrix(res)
                t += res.timings["assembly"] - before  # counted as assembly, not as the solve
                solve = self._factorize(H)
                p0 = -solve(g)
            Y = np.column_stack([solve(Ct[:, k]) for k in range(m)]) if np.any(Ct) else np.zeros_like(Ct)
            schur = D - Ct.T @ Y
            q = np.linalg.solve(schur, -g_s - Ct.T @ p0)
            p_free = p0 - Y @ q
            descent = float(g @ p_free + g_s @ q)
            if not (np.all(np.isfinite(p_free)) and np.all(np.isfinite(q)) and descent < 0.0):
                raise NotPositiveDefinite("bordered tool system")
        except (NotPositiveDefinite, np.linalg.LinAlgError):
            # the tool block alone (the body's direction as without tools): a descent direction as H and D are PD
            p_free = self._direction(H, g, res)
            dd = np.diag(D)
            q = np.where(dd > 0.0, -g_s / np.where(dd > 0.0, dd, 1.0), 0.0)
        res.timings["linear_solve"] += time.perf_counter() - t
        return p_free, q

    def _fold_distorts(self, p_free: np.ndarray, g: np.ndarray) -> bool:
        """Whether the matrix just factorised was folded and the fold distorts its direction ``p_free`` = −M⁻¹g:
        its Newton residual ‖K·p‖ or the fold's stiffening along it beyond ``NewtonSettings.fold_distortion`` /
        ``fold_stiffening`` (K = exact − M). After ``fold_stop_after`` distorting folds in a row (in a system of
        ``fold_stop_min_dofs`` free DOFs or more) it turns the pattern's folding off for the rest of the step."""
        pattern = self.system.contact_pattern
        if pattern is None or not pattern.last_folded:
            return False
        K = pattern.fold_correction
        keep = None if self._held is None else ~self._held
        residual = K @ p_free if keep is None else keep * (K @ (keep * p_free))
        curvature = -float(g @ p_free)  # pᵀMp, M·p being −g
        distorts = not (
            np.linalg.norm(residual) <= self.settings.fold_distortion * np.linalg.norm(g)
            and abs(float(p_free @ residual)) <= self.settings.fold_stiffening * curvature
        )
        self._distorted_run = self._distorted_run + 1 if distorts else 0
        cfg = self.settings
        if 0 < cfg.fold_stop_after <= self._distorted_run and g.size >= cfg.fold_stop_min_dofs:
            pattern.folding = False  # the rest of the step grows (NewtonSettings.fold_stop_after)
        return distorts

    def _unfolded_matrix(self, res: NewtonResult) -> sp.csr_matrix:
        """The last folded matrix without folding, on the pattern grown by its folded couplings (held DOFs held)."""
        res.distorted_folds += 1
        t = time.perf_counter()
        H = self._hold(self.system.contact_pattern.exact_matrix())
        res.timings["assembly"] += time.perf_counter() - t
        return H

    def _undistorted(self, p_free: np.ndarray, g: np.ndarray, res: NewtonResult) -> np.ndarray:
        """``p_free``, the direction of the matrix just factorised, unless that matrix was folded and the fold
        distorts the direction (:meth:`_fold_distorts`): then the direction of the exact matrix."""
        if not self._fold_distorts(p_free, g):
            return p_free
        return self._direction(self._unfolded_matrix(res), g, res)

    def _exact_direction(self, M, g: np.ndarray, p_folded: np.ndarray, res: NewtonResult) -> np.ndarray:
        """Exact Newton direction −H⁻¹g when ``M`` (just factorised) is a folded majorant of H.

        Conjugate gradients on H = M + K (K = ``contact_pattern.fold_correction``), preconditioned by M's
        factor and started from M's direction (:func:`~idp.solver.pcg.pcg_from_majorant`). Falls back to
        growing the pattern and factorising H itself if CG has not converged within the cap."""
        s, cfg = self.system, self.settings
        K = s.contact_pattern.fold_correction
        t = time.perf_counter()
        try:
            keep = None if self._held is None else ~self._held

            def apply(v):
                if keep is None:
                    return M @ v + K @ v
                return M @ v + keep * (K @ (keep * v))

            p, its, ok = pcg_from_majorant(apply, self._last_solve, -g, p_folded, cfg.pcg_rtol, cfg.pcg_max_iterations)
        except SolverError:  # no usable factor of M (its direction was a gradient-descent fallback)
            its, ok = 0, False
        res.timings["linear_solve"] += time.perf_counter() - t
        res.pcg_iterations += its
        if ok:
            return p
        t = time.perf_counter()
        H = self._hold(s.contact_pattern.exact_matrix())
        res.timings["assembly"] += time.perf_counter() - t
        res.exact_refactorizations += 1
        return self._direction(H, g, res)

    # -- main loop -------------------------------------------------------------------------
    def solve(
        self, x_prev: np.ndarray, *, start: np.ndarray | None = None, target_at_rest: bool = False
    ) -> tuple[np.ndarray, NewtonResult]:
        """Minimise the step energy S(x) = ½‖x − x_prev‖²_M + h·E(x) + B(x), iterating from ``start`` (a certified
        state; default ``x_prev``). The inertia target ``x_prev`` = x_t is the previous step's state in the
        artificial time stepping, or another state a driver asks for (animation repair: the input frame).

        ``target_at_rest``: the caller states that every elastic term is at its rest state at ``x_prev`` (repair
        makes the input frame the rest shape). Then, if the straight move from ``start`` to ``x_prev`` is
        collision- and inversion-free and no contact pair is within d̂ there, S(x_prev) is S's lower bound 0 and
        ``x_prev`` itself, bit for bit, is the minimiser: it is returned with 0 Newton iterations
        (:attr:`NewtonResult.exact`). Otherwise Newton runs as usual.

        With a step constraint (``system.step_constraint``, §4.3) the first iterate is its feasible move of the
        bound vertices, its penalty joins S while it is on, its held DOFs do not move, and the loop stops only
        once it is settled (see :mod:`idp.solver.constraint`)."""
        s = self.system
        t_start = time.perf_counter()
        res = NewtonResult()
        x = (x_prev if start is None else start).copy()
        self._constraint = s.step_constraint
        self._held = None
        self._skip_stencils = {}
        self._labels = None
        if self.settings.island_steps and s.contact is not None and s.contact.compiled:
            labels = body_labels(s)
            self._labels = labels if labels.num_labels >= 2 else None
        # on after a step CCD cut short; with islands, one switch per body (each as it would be alone)
        bodies = 1 if self._labels is None else self._labels.num_labels
        self._lookahead = LookaheadSwitch(self.settings.contact_lookahead > 1.0, bodies)
        if s.contact is not None:
            s.contact.hold_still(None)  # last step's held vertices move towards their new targets
        self._distorted_run = 0
        if s.contact_pattern is not None:
            s.contact_pattern.folding = True  # each step tries folding again
        try:
            return self._solve(x, x_prev, res, t_start, target_at_rest)
        finally:
            if s.contact is not None:
                s.contact.hold_still(None)

    def _solve(
        self, x: np.ndarray, x_prev: np.ndarray, res: NewtonResult, t_start: float, target_at_rest: bool
    ) -> tuple[np.ndarray, NewtonResult]:
        s, cfg, c = self.system, self.settings, self._constraint
        n, d = x.shape
        free = s.dof_map.free_dofs
        sqrt_h = math.sqrt(s.h)
        if target_at_rest and self._target_is_minimiser(x, x_prev, res):
            if c is not None:
                c.accept(x_prev)
            res.converged, res.exact, res.decrement = True, True, 0.0
            # no pair within d̂ at the target (checked above): the minimum distance is inf, as for no contact
            return x_prev.copy(), res

        def feasible(x_: np.ndarray, P_: np.ndarray) -> float:  # the constraint's moves, timed with the step's
            return self.feasible_step(x_, P_, res)

        if c is not None:
            x = c.begin(x, feasible)
            self._update_held(c, free)
        ev = self._contact_eval(x, res)
        if ev is not None:
            self._init_kappa(x, x_prev, ev)
        prev_min_d = s.contact.kappa_distance(ev) if ev is not None else math.inf
        energy, el, bar = self._energy(x, x_prev, ev)
        if not math.isfinite(energy):
            raise SolverError(
                "step energy is not finite at the start of the step (inverted element or contact at zero distance)"
            )

        for it in range(1, cfg.max_iterations + 1):
            interrupts.checkpoint()  # a SIGTERM or Ctrl-C recorded during the last iteration stops here
            res.iterations = it
            t = time.perf_counter()
            self._lookahead_used = np.zeros(1, dtype=bool)
            g_full, H = self._derivatives(x, x_prev, ev)
            res.lookahead_iterations += bool(self._lookahead_used.any())
            g = g_full[free]
            if self._held is not None:
                g[self._held] = 0.0
                H = self._hold(H)
            res.timings["assembly"] += time.perf_counter() - t
            if not np.all(np.isfinite(g)):
                raise SolverError(f"non-finite gradient at Newton iteration {it}")

            tools: list = c.tool_moves(x) if c is not None and hasattr(c, "tool_moves") else []
            if tools:
                p_free, q = self._direction_with_tools(H, g, g_full, ev, tools, res)
                tool_move = max(abs(float(qk)) * float(np.abs(P).max()) for qk, (_, P) in zip(q, tools, strict=True))
            else:
                p_free, tool_move = self._direction(H, g, res), 0.0
                p_free = self._undistorted(p_free, g, res)
            res.decrement = max(self._measure(p_free), tool_move) / sqrt_h
            within_tol = res.decrement <= cfg.tol
            body_within = self._bodies_within(p_free, cfg.tol) if self._lookahead.any_on else None
            converged = self._lookahead.may_end_solve(within_tol, self._lookahead_used, body_within)
            res.unconfirmed = ""
            if within_tol and not converged:  # a majorant's direction: the next iteration, exact, judges
                res.unconfirmed = "its direction came from the contact look-ahead's majorant, not yet confirmed"
            if converged and not tools and s.contact_pattern is not None and s.contact_pattern.last_folded:
                # the matrix was a folded majorant: judge convergence on the exact Newton direction
                p_free = self._exact_direction(H, g, p_free, res)
                res.decrement = self._measure(p_free) / sqrt_h
                converged = res.decrement <= cfg.tol
            del H  # the matrix is not needed past the direction: not alive during the line search or the next assembly
            if self._held is not None:  # exactly still (their pairs among themselves are left out of CCD)
                p_free[self._held] = 0.0

            p = np.zeros(n * d)
            p[free] = p_free
            P = p.reshape(n, d)
            for qk, (tool_vertices, tool_move_k) in zip(q if tools else [], tools, strict=True):
                P[tool_vertices] += qk * tool_move_k

            # feasible step: inversion filter, then CCD on the shortened step, then backtracking
            self._may_extend = cfg.extrapolate > 1.0 and not tools
            self._islands_now = self._labels is not None and not tools  # a tool's one unknown couples its bodies
            accepted, alpha, alpha_inv, alpha_ccd, trial = self._filtered_step(x, P, x_prev, energy, ev, res)
            res.inversion_alphas.append(alpha_inv)
            res.decrements.append(res.decrement)
            res.ccd_alphas.append(alpha_ccd)
            if accepted:
                x, ev, energy, el, bar = trial
                res.alphas.append(alpha)
                # on while CCD keeps cutting the moves short, off again after a move it lets through, and for the
                # rest of the solve once it alternates futilely with exact directions (idp.solver.lookahead); never
                # while kinematic tools move: their bordered system (_direction_with_tools) couples a tool to the
                # body through the exact contact Hessian only, so look-ahead blocks would stiffen the body's side of
                # a pair and not the tool's, and the tool would press the body without it giving way (a plate
                # squashing a ball: blocked after one step, gaps crushed to ~1e-10; docs/handles.md)
                cut = alpha_ccd if self._body_ccd is None else self._body_ccd
                self._lookahead.after_step(cut, self._lookahead_used, ev is not None and not tools)
            else:
                res.alphas.append(0.0)
                if not converged:
                    res.line_search_failed = True
                    break

            if ev is not None:
                min_d = s.contact.kappa_distance(ev)
                kappa_before = s.contact.kappa
                s.contact.update_kappa(prev_min_d, min_d)
                prev_min_d = min_d
                if s.contact.kappa != kappa_before:  # the objective changed: re-evaluate it
                    energy, el, bar = self._energy(x, x_prev, ev)
            self._check_iterate(x, it, res)
            kill_point("newton")  # crash-safety tests only (idp._faults); nothing otherwise
            changed = False
            if c is not None:
                in_contact = ev is not None and ev.num_active > 0
                x_new, changed = c.after_iterate(
                    x,
                    converged,
                    feasible,
                    contact_limited=alpha_ccd < 1.0,
                    in_contact=in_contact,
                    ccd_fraction=alpha_ccd,
                )
                moved = x_new is not x  # bound vertices snapped onto their targets (a feasible move)
                x = x_new
                still_changed = changed and self._update_held(c, free)
                if moved or still_changed:  # (pairs among newly held vertices leave the barrier)
                    ev = self._contact_eval(x, res)
                if changed:
                    energy, el, bar = self._energy(x, x_prev, ev)
            if converged and not changed and (c is None or c.settled):
                res.converged = True
                break
            if converged:
                res.unconfirmed = "the step constraint (handles, targets) changed or had not settled"
            if cfg.max_seconds is not None and time.perf_counter() - t_start > cfg.max_seconds:
                res.hit_wall_limit = True  # x is an accepted (feasible, certified-to-be) iterate
                break
        else:
            res.hit_iteration_cap = True

        res.energy, res.elastic_energy, res.barrier_energy = energy, el, bar
        if ev is not None:
            res.num_contacts = ev.num_active
            res.kappa = s.contact.kappa
            res.min_distance = s.contact.min_distance(ev)
        return x, res

    def _target_is_minimiser(self, x: np.ndarray, target: np.ndarray, res: NewtonResult) -> bool:
        """Whether the inertia target (elastic terms at rest there) is reachable from ``x`` by a feasible straight
        move, moves no pinned DOF and has no contact pair within d̂ (so the barrier is 0 there)."""
        s = self.system
        P = target - x
        if np.any(P.ravel()[~s.dof_map.free_mask] != 0.0):
            return False
        if s.contact is not None:
            t = time.perf_counter()
            within = s.contact.any_within_dhat(target)
            res.timings["contact_build"] += time.perf_counter() - t
            if within:
                return False
        return not np.any(P) or self.feasible_step(x, P, res) >= 1.0

    def _stencils_on_held(self, held_all: np.ndarray) -> dict[int, np.ndarray]:
        """Per term index (the shell terms, :class:`StencilTerm`): the stencils whose every DOF is
        held or not optimised. Their gradient lands only on DOFs the step zeroes and their Hessian only on rows it
        drops, so the Newton loop skips them (the mannequin's held head: half the triangles and hinges)."""
        s = self.system
        if not held_all.any():
            return {}
        inactive = held_all | ~s.dof_map.free_mask
        out = {}
        for i, wt in enumerate(s.terms):
            if not isinstance(wt.term, StencilTerm):
                continue
            skip = inactive[wt.term.element_dofs()].all(axis=1)
            if skip.any():
                out[i] = skip
        return out

    def _update_held(self, c, free: np.ndarray) -> bool:
        """Takes the constraint's held DOFs; tells the contact model which vertices stay still (every DOF held),
        so pairs among them leave its collision sets and CCD. Returns whether that vertex set changed."""
        held_all = c.held_dofs()
        held = held_all[free]
        self._held = held if held.any() else None
        self._skip_stencils = self._stencils_on_held(held_all)
        contact = self.system.contact
        if contact is None:
            return False
        still = held_all.reshape(-1, self.system.dim).all(axis=1)
        if getattr(c, "moves_obstacles", True):  # a tool moving in the step can reach pairs of held vertices
            still[:] = False
        before = contact.still
        contact.hold_still(still if still.any() else None)
        after = contact.still
        if before is None or after is None:
            return before is not after
        return not np.array_equal(before, after)
