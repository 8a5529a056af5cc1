"""IPC contact through ipctk: collision mesh, log barrier with adaptive stiffness, CCD, intersection test.

Positions handed to this class are the full simulation array ``x`` (n, d); the class maps them to the
collision (surface) mesh. ipctk pitfalls handled here: positions are always passed as (n, d) arrays
(a flattened vector is silently misread), distances from ipctk are SQUARED, and the stiffness lives
inside ``BarrierPotential`` (rebuilt when κ changes).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import ipctk
import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:  # imported lazily at run time (compiling it is only needed for the compiled barrier)
    from idp.contact.compiled_barrier import CollisionSet

BROAD_PHASES = {
    "lbvh": ipctk.LBVH,
    "hash_grid": ipctk.HashGrid,
    "spatial_hash": ipctk.SpatialHash,
    "sweep_and_prune": ipctk.SweepAndPrune,
    "brute_force": ipctk.BruteForce,
}


#: Tight Inclusion's conservative rescaling in ipctk: a pair at distance d may come within min((1 − r)·d, 1e-4)
#: in one CCD-bounded step (ipctk's default r = 0.8). Almost every Newton step is cut by CCD, mostly at a pair
#: arriving from a few d̂ away that ipctk stops at 1e-4 = 0.1 d̂ whatever r; a larger r lets pairs closer than
#: 1e-4/(1 − r) come nearer. Measured, Newton iterations / fill at step 60 (reference: 236 / 97.68 % and
#: 335 / 98.79 %), r = 0.8 / 0.9 / 0.95 / 0.97 / 0.98: bunny_700 246 / 246 / 238 / 236 / 232 iterations, 97.96 /
#: 97.96 / 97.88 / 98.02 / 97.92 %; bunny_3376 347 / 347 / 334 / 337 / 325 iterations, 98.89 / 98.89 / 98.75 /
#: 98.81 / 98.76 %. 0.97 keeps both fills above the reference's. The smallest gap seen shrinks (bunny_3376,
#: 1.0e-4 → 3.7e-5), still far from the reference's 1.6e-6.
TI_CONSERVATIVE_RESCALING = 0.97


def make_ccd(name: str):
    """Narrow-phase CCD: ``additive`` (conservative advancement, fast) or ``tight_inclusion``.

    Tight Inclusion's default tolerance (1e-6, 1e7 iterations) is 30–100× slower on near-contact
    pairs; 1e-4 / 1e5 stays conservative (measured in the project's dependency notes)."""
    if name == "additive":
        return ipctk.AdditiveCCD()
    if name == "tight_inclusion":
        return ipctk.TightInclusionCCD(1e-4, 100000, TI_CONSERVATIVE_RESCALING)
    raise ValueError(f"unknown CCD method {name!r}; choose 'additive' or 'tight_inclusion'")


BARRIERS = ("compiled", "ipctk")
NEAR_CONTACT = 1e-4  # gaps below NEAR_CONTACT·d̂: additive CCD plus conservative advancement of those pairs
NEAR_KEEP = 0.1  # ... each keeping 10 % of its gap (the reference keeps 10 % of every gap)
#: A candidate whose gap at the start of a move is below this share of its relative move (M of
#: :mod:`idp.contact.ccd_filter`) is checked by conservative advancement with exact distances instead of the
#: narrow phase, keeping the gap share the narrow phase would keep. Tight Inclusion on such pairs is slow and
#: answers far too early: one edge–edge pair of the beam loop in tests/stepper/test_handles.py, crossing edges
#: 1.1e-7 apart whose relative move of 0.022 takes them apart (4e-6 at mid-move), cost 5.7 s and returned
#: α = 0.049 (tolerance 1e-4 to 1e-6, 1e4 to 1e6 iterations alike); the same pair shifted to 3e-6, 1e-5 and
#: 1e-4 apart: 2.7 s (α = 0.37), 0.38 s and 0.016 s (no contact). Advancement costs about 2/share distance
#: evaluations a pair at this share (microseconds).
TIGHT_GAP_SHARE = 1e-2


@contextmanager
def one_ipctk_thread() -> Iterator[None]:
    """Run the ipctk calls inside on one thread, so that what they return depends on their inputs alone.

    The CCD narrow phase: ipctk's ``compute_collision_free_stepsize`` checks its pairs on TBB threads that share the
    earliest time of impact found so far, and passes it to each next pair as the end of the interval to search;
    Tight Inclusion's answer for a pair depends on that end (its interval splitting starts from it), so with more
    than one thread the step depended on the schedule: the beam loop of tests/stepper/test_handles.py took one of
    two Newton paths from run to run (step 26: 43 or 45 iterations, the first in 5 of 14 runs on ipctk's 2 threads,
    numba on one, ``PYTHONHASHSEED`` fixed or not; the same in 6 of 6 with ipctk on one thread), and a run resumed
    from a checkpoint need not be the run uninterrupted. On one thread the pairs go in idp's order (by increasing
    first possible contact, :func:`idp.contact.ccd_filter.ccd_order`), which hands the early times of impact to the
    later pairs as the threads did.

    The barrier without the compiled path (2D, ``barrier = "ipctk"``): ipctk builds its collision set and candidates
    on its threads (so their order follows the schedule) and sums the barrier's value, gradient and Hessian over
    per-thread parts, so the last bits depended on the schedule (tests/contact/test_barrier_threads.py: 9
    values, 14 gradients, 19 Hessians in 20 evaluations of one configuration on two threads)."""
    threads = ipctk.get_num_threads()
    if threads == 1:
        yield
        return
    ipctk.set_num_threads(1)
    try:
        yield
    finally:
        ipctk.set_num_threads(threads)


@dataclass
class ContactEvaluation:
    """Collision set at one configuration, with what the Newton loop needs from it."""

    collisions: ipctk.NormalCollisions | CollisionSet
    surface_positions: np.ndarray
    num_active: int


class HessianBlockStream:
    """The projected per-collision Hessian blocks of one or more collision sets (the active pairs, then a look-ahead
    set), numbered one after the other, computed for a range of collisions at a time into the caller's buffer.

    A matrix assembly that adds each range before computing the next never holds every block: at bunnyx30_13K
    with the contact look-ahead the blocks of one Newton matrix (up to ≈ 63,000 of 1.2 KB) were 73 MB alive at
    once, the run's peak memory. ``block_verts`` (m, 4) int32 (output vertex ids, −1 padded) is small and kept
    whole: row c is written when a range covering c is computed. Each block is the one the whole set gives
    (:func:`idp.contact.compiled_barrier.barrier_hessian_blocks` on views of its arrays)."""

    def __init__(self, cb: Any, sets: list[tuple[Any, float, float]], positions: np.ndarray, vertex_map: np.ndarray):
        self._cb = cb
        self._sets = sets  # (collision set, activation distance, stiffness)
        self._positions = positions
        self._vertex_map = np.ascontiguousarray(vertex_map, dtype=np.int64)
        self._offsets = np.cumsum([0] + [len(cs) for cs, _, _ in sets])
        self.block_verts = np.empty((int(self._offsets[-1]), 4), np.int32)

    def __len__(self) -> int:
        return int(self._offsets[-1])

    @property
    def n_ahead(self) -> int:
        """Blocks after the first set's (the look-ahead set's)."""
        return len(self) - int(self._offsets[1])

    def ahead_vertices(self) -> np.ndarray:
        """(k, 4) collision-mesh vertex ids (−1 padded) of the look-ahead sets' pairs (those after the first set)."""
        parts = [cs.verts for cs, _, _ in self._sets[1:]]
        return np.concatenate(parts) if parts else np.zeros((0, 4), dtype=np.int32)

    def blocks(self, c0: int, c1: int, buffer: np.ndarray) -> np.ndarray:
        """The blocks of collisions c0 … c1 − 1, written into ``buffer[: c1 − c0]`` ((≥ c1 − c0, 12, 12),
        C-contiguous), which is returned; fills ``block_verts[c0:c1]``."""
        out = buffer[: c1 - c0]
        for k, (cs, dhat, kappa) in enumerate(self._sets):
            lo, hi = max(c0, int(self._offsets[k])), min(c1, int(self._offsets[k + 1]))
            if lo >= hi:
                continue
            off = int(self._offsets[k])
            self._cb.barrier_hessian_blocks(
                cs,
                self._positions,
                dhat,
                kappa,
                self._vertex_map,
                True,
                out=(self.block_verts[lo:hi], out[lo - c0 : hi - c0]),
                rows=(lo - off, hi - off),
            )
        return out


class ContactModel:
    """Barrier B(x) = κ Σ b(d_i, d̂) over the active surface pairs, plus CCD and intersection queries."""

    def __init__(
        self,
        positions: np.ndarray,
        surface: np.ndarray,
        num_dynamic_vertices: int,
        dhat: float,
        *,
        ccd: str = "tight_inclusion",
        broad_phase: str = "lbvh",
        kappa: float | None = None,
        adaptive_kappa: bool = True,
        barrier: str = "compiled",
        kappa_init: str = "every_step",
    ):
        """``surface``: boundary triangles (3D) or segments (2D) in global vertex ids; vertices with
        id >= ``num_dynamic_vertices`` are static obstacles (pairs of two static vertices are skipped).
        ``kappa``: None for IPC's automatic initial stiffness, or a fixed initial value.
        ``barrier``: ``compiled`` (collision set, barrier and Hessian blocks in arrays,
        :mod:`idp.contact.compiled_barrier`; 3D only, 2D falls back) or ``ipctk`` (ipctk's
        ``NormalCollisions`` and ``BarrierPotential``); the same energy either way. ``kappa_init``: with the
        automatic κ, IPC's gradient balance at the start of ``every_step`` (never lowering κ), or ``once``, at the
        first step that has a pair within d̂ (:meth:`initialize_kappa`)."""
        if barrier not in BARRIERS:
            raise ValueError(f"unknown barrier implementation {barrier!r}; choose one of {BARRIERS}")
        self.dim = positions.shape[1]
        self.dhat = float(dhat)
        surface = np.asarray(surface, dtype=np.int32)
        if self.dim == 3:
            faces = surface
            edges = ipctk.edges(faces) if len(faces) else np.zeros((0, 2), dtype=np.int32)
        else:
            faces = np.zeros((0, 3), dtype=np.int32)
            edges = surface
        self.mesh = ipctk.CollisionMesh.build_from_full_mesh(np.ascontiguousarray(positions, dtype=float), edges, faces)
        self.to_full = np.asarray(self.mesh.to_full_vertex_id(), dtype=np.int64)
        full_to_cm = np.full(positions.shape[0], -1, dtype=np.int64)
        full_to_cm[self.to_full] = np.arange(self.to_full.size)
        self.full_to_collision = full_to_cm
        n_dyn_cm = int(np.searchsorted(self.to_full, num_dynamic_vertices))
        self.mesh.can_collide = ipctk.make_static_obstacle_filter(n_dyn_cm)
        self._broad_phase_name = broad_phase
        self._ccd_name = ccd
        self._ccd = make_ccd(ccd)
        self._fallback_ccd = make_ccd("additive")
        self.ccd_fallbacks = 0
        self.kappa_auto = kappa is None
        if kappa_init not in ("every_step", "once"):
            raise ValueError(f"unknown kappa_init {kappa_init!r}; choose 'every_step' or 'once'")
        self.kappa_init_once = kappa_init == "once"
        self.kappa_initialized = False
        self.adaptive_kappa = adaptive_kappa
        self.kappa = 0.0 if kappa is None else float(kappa)
        self.kappa_max = 0.0 if kappa is None else 100.0 * float(kappa)
        self._potential_cache: tuple[float, object] | None = None
        self.bbox_diagonal = float(ipctk.world_bbox_diagonal_length(self.surface_positions(positions)))
        self.compiled = barrier == "compiled" and self.dim == 3
        self._kappa_exempt: np.ndarray | None = None  # collision-mesh vertices left out of κ's distance
        self._excluded_fv = np.zeros(0, dtype=np.int64)  # touching input pairs left out (exclude_touching)
        self._excluded_ee = np.zeros(0, dtype=np.int64)
        self.num_dynamic_collision_vertices = n_dyn_cm
        self._move_bounds: tuple | None = None  # (sweep candidates, d(0), M) of the last filtered CCD
        self._still: np.ndarray | None = None  # collision-mesh vertices held still in the Newton step at hand
        self._prescribed: np.ndarray | None = None  # collision-mesh vertices whose own pairs are left out for good
        # the last evaluation and what it depended on besides the positions (:meth:`_reusable_evaluation`)
        self._last_evaluation: tuple | None = None
        if self.compiled:
            from idp.contact import compiled_barrier
            from idp.contact._broad_phase import surface_candidates

            self._cb = compiled_barrier
            self._surface_candidates = surface_candidates
            self._edges = np.ascontiguousarray(self.mesh.edges, dtype=np.int32)
            self._faces = np.ascontiguousarray(self.mesh.faces, dtype=np.int32)
            rest = np.asarray(self.mesh.rest_positions)
            self._edge_rest_len2 = (
                np.ascontiguousarray(((rest[self._edges[:, 1]] - rest[self._edges[:, 0]]) ** 2).sum(axis=1))
                if len(self._edges)
                else np.zeros(0)
            )

    # -- preserved touching pairs ------------------------------------------------
    def exclude_touching(self, x: np.ndarray, tolerance: float) -> list[tuple[list[int], list[int]]]:
        """Leave out of the barrier and CCD every surface pair closer than ``tolerance`` at ``x``; returns them as
        (vertices of one primitive, vertices of the other) in full-mesh ids (a vertex vs a triangle or an edge, or
        an edge vs an edge).

        Only for preserved input crossings (paper §5.5): an artist's crossing can hold primitives that touch
        exactly (the mannequin's rest pose has two edge pairs at distance 0 inside its crossings), where the
        barrier is infinite and CCD allows no motion. Those pairs belong to the crossing, which is kept anyway;
        every other pair, including every other pair of the same primitives' neighbours, stays guarded. CCD
        leaves them out through a vertex-pair filter on the collision mesh (a pair is skipped only when all
        its cross vertex pairs are filtered), the compiled barrier by dropping their candidates."""
        vs = self.surface_positions(x)
        if self.compiled:
            fv, ee = self._candidates(vs, None, every_pair=True)
        else:
            fv = ee = None
        tol2 = float(tolerance) ** 2
        pairs: list[tuple[list[int], list[int]]] = []  # (one side's vertices, the other side's), collision ids
        if fv is not None and ee is not None:
            touch = np.flatnonzero(self._candidate_sqdist(vs, fv, ee) <= tol2)
            nf = fv.shape[0]
            fv_touch, ee_touch = touch[touch < nf], touch[touch >= nf] - nf
            self._excluded_fv = np.unique(fv[fv_touch, 0].astype(np.int64) * vs.shape[0] + fv[fv_touch, 1])
            self._excluded_ee = np.unique(ee[ee_touch, 0].astype(np.int64) * len(self._edges) + ee[ee_touch, 1])
            for f, v in fv[fv_touch]:
                pairs.append(([int(v)], [int(i) for i in self._faces[f]]))
            for a, b in ee[ee_touch]:
                pairs.append(([int(i) for i in self._edges[a]], [int(i) for i in self._edges[b]]))
        else:
            c = ipctk.NormalCollisions()
            with one_ipctk_thread():
                c.build(self.mesh, vs, float(tolerance) + 1e-300, 0.0, self.broad_phase())
            E, F = self.mesh.edges, self.mesh.faces
            for i in range(len(c)):
                ids = [int(j) for j in c[i].vertex_ids(E, F) if j >= 0]
                if float(c[i].compute_distance(c[i].dof(vs, E, F))) <= tol2:
                    split = 2 if "EdgeEdge" in type(c[i]).__name__ else 1  # edge–edge, else a vertex vs the rest
                    pairs.append((ids[:split], ids[split:]))
        if not pairs:
            return []
        if self.num_dynamic_collision_vertices < vs.shape[0]:
            from idp.errors import SceneError

            raise SceneError(
                f"{len(pairs)} surface pair(s) of the preserved input touch exactly; leaving them out is not supported "
                "with static obstacles in the scene yet"
            )
        explicit = {}
        for side_a, side_b in pairs:
            for i in side_a:
                for j in side_b:
                    if i != j:
                        explicit[(min(i, j), max(i, j))] = False
        self.mesh.can_collide = ipctk.make_sparse_filter(explicit, True)
        full = self.to_full
        return [([int(full[i]) for i in a], [int(full[i]) for i in b]) for a, b in pairs]

    # -- vertices held still during a Newton step --------------------------------
    def hold_still(self, vertices: np.ndarray | None) -> None:
        """Full-mesh vertex mask (n,) of vertices that do not move until the next call (a Newton step's held
        Dirichlet vertices, §4.3), or None. Until then the compiled barrier's collision sets and CCD leave out
        every pair whose vertices are all still or static: its distance cannot change, so its barrier term is a
        constant of the step (its gradient lies only on held DOFs) and it cannot collide. The mannequin's
        prescribed head holds 92 % of the ~464,000 pairs within d̂ of the repair (measured on Kick frame 1).
        The step's energy then omits that constant, so energies are comparable only between calls with the same
        mask (the Newton loop re-evaluates when its held set changes). Valid only while no obstacle vertex moves in
        the step either (obstacle vertices count as static here; the Newton loop sets no mask when its constraint
        moves tools). The ipctk barrier path (2D) ignores it."""
        if vertices is None or not self.compiled:
            self._still = None
            return
        mask = np.asarray(vertices, dtype=bool)[self.to_full]
        self._still = mask if mask.any() else None

    def leave_out_pairs_among(self, vertices: np.ndarray | None) -> None:
        """Full-mesh vertex mask (n,) of a prescribed group whose pairs among themselves leave the barrier and CCD
        for the rest of the run (None: none), as the authors' code treats pairs of Dirichlet vertices: their
        relative motion is prescribed, so the group follows its prescribed motion exactly, also where its own
        parts pass through each other (an animation's head whose input crosses itself: Kick frame 10). Every pair
        with a vertex outside the group stays guarded. Compiled barrier only (its broad phase skips them)."""
        if vertices is None:
            self._prescribed = None
            return
        if not self.compiled:
            raise ValueError("leaving out the pairs among prescribed vertices needs the compiled 3D barrier")
        mask = np.asarray(vertices, dtype=bool)[self.to_full]
        self._prescribed = mask if mask.any() else None

    @property
    def still(self) -> np.ndarray | None:
        """Collision-mesh vertex mask set by :meth:`hold_still` (None: every vertex may move)."""
        return self._still

    def _filter_excluded(self, fv: np.ndarray, ee: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray]:
        """Candidates without the excluded touching pairs (:meth:`exclude_touching`)."""
        if self._excluded_fv.size and fv.size:
            keep = ~np.isin(fv[:, 0].astype(np.int64) * nv + fv[:, 1], self._excluded_fv, assume_unique=False)
            fv = fv if keep.all() else fv[keep]
        if self._excluded_ee.size and ee.size:
            keep = ~np.isin(ee[:, 0].astype(np.int64) * len(self._edges) + ee[:, 1], self._excluded_ee)
            ee = ee if keep.all() else ee[keep]
        return fv, ee

    # -- geometry -------------------------------------------------------------
    def broad_phase(self):
        return BROAD_PHASES[self._broad_phase_name]()

    def surface_positions(self, x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(x[self.to_full], dtype=float)

    def collision_dofs(self) -> np.ndarray:
        """Global DOF index of every collision-mesh DOF (interleaved)."""
        d = self.dim
        return (self.to_full[:, None] * d + np.arange(d)[None, :]).ravel()

    # -- barrier --------------------------------------------------------------
    def evaluate(self, x: np.ndarray, candidates=None) -> ContactEvaluation:
        """Active collision set at x. ``candidates`` from :meth:`sweep_candidates` (valid for any point of
        the swept segment) replaces the broad phase, so line-search trials skip it. The compiled path hands back its
        last evaluation when nothing it depends on changed (:meth:`_reusable_evaluation`)."""
        vs = self.surface_positions(x)
        if self.compiled:
            last = self._reusable_evaluation(vs)
            if last is not None:
                return last
            fv, ee = candidates if candidates is not None else self._candidates(vs, None)
            cs = self._cb.build_collision_set(vs, self._edges, self._faces, fv, ee, self.dhat, self._edge_rest_len2)
            ev = ContactEvaluation(cs, vs, len(cs))
            self._last_evaluation = (self._evaluation_inputs(), ev)
            return ev
        c = ipctk.NormalCollisions()
        with one_ipctk_thread():
            if candidates is not None:
                c.build(candidates, self.mesh, vs, self.dhat, 0.0)
            else:
                c.build(self.mesh, vs, self.dhat, 0.0, self.broad_phase())
        return ContactEvaluation(c, vs, len(c))

    def _evaluation_inputs(self) -> tuple:
        """What a compiled collision set depends on besides the positions: d̂ by value, the pair selections by
        identity (every change of them makes a new array: :meth:`hold_still`, :meth:`leave_out_pairs_among`,
        :meth:`exclude_touching`)."""
        return (self.dhat, self._still, self._prescribed, self._excluded_fv, self._excluded_ee)

    def _reusable_evaluation(self, vs: np.ndarray) -> ContactEvaluation | None:
        """The last evaluation when it was made at exactly these surface positions with the same inputs, else None.

        A time step starts where the previous one's accepted iterate ended, and the collision set there is the one
        its line search already built (from the move's candidates, which hold every pair within d̂ at any point of
        the move, so the same pairs a fresh broad phase finds; their order, and so the rounding of sums over them,
        may differ). bunny_700's 60 steps: one broad phase and classification each (≈ 3 ms of a 30–50 ms step)."""
        last = self._last_evaluation
        if last is None:
            return None
        (dhat, *selections), ev = last
        now_dhat, *now_selections = self._evaluation_inputs()
        same = dhat == now_dhat and all(a is b for a, b in zip(selections, now_selections, strict=True))
        return ev if same and np.array_equal(ev.surface_positions, vs) else None

    def any_within_dhat(self, x: np.ndarray) -> bool:
        """Whether some pair (of those :meth:`evaluate` would see) is closer than d̂ at x, without building the
        collision set (the compiled barrier classifies the candidates and stops there)."""
        if not self.compiled:
            return self.evaluate(x).num_active > 0
        vs = self.surface_positions(x)
        fv, ee = self._candidates(vs, None)
        return bool(np.any(self._candidate_sqdist(vs, fv, ee) < self.dhat**2))

    def _candidate_sqdist(self, vs: np.ndarray, fv: np.ndarray, ee: np.ndarray) -> np.ndarray:
        """Squared distance of every (fv, then ee) candidate at surface positions ``vs`` (compiled barrier)."""
        n = fv.shape[0] + ee.shape[0]
        ctype, sqd, eps = np.empty(n, np.int64), np.empty(n), np.empty(n)
        if n:
            self._cb.classify(vs, self._faces, self._edges, fv, ee, self._edge_rest_len2, ctype, sqd, eps)
        return sqd

    def _candidates(
        self, v0: np.ndarray, v1: np.ndarray | None, *, every_pair: bool = False, still: np.ndarray | None = None
    ):
        """Broad-phase (fv, ee) candidates within d̂ (of the sweep v0 → v1 when v1 is given), without the pairs
        of still vertices (``still``, default those of :meth:`hold_still`) and of the prescribed group
        (:meth:`leave_out_pairs_among`) unless ``every_pair``, and without excluded touching pairs."""
        fv, ee = self._surface_candidates(
            v0,
            v1,
            self._edges,
            self._faces,
            self.dhat,
            self.num_dynamic_collision_vertices,
            None if every_pair else (self._still if still is None else still),
            None if every_pair else self._prescribed,
            co_moving=v1 is not None,  # a falling or carried bundle's sweep: only its own deformation counts
        )
        if self._excluded_fv.size or self._excluded_ee.size:
            fv, ee = self._filter_excluded(fv, ee, v0.shape[0])
        return fv, ee

    def sweep_candidates(self, x0: np.ndarray, x1: np.ndarray, *, moving_only: bool = False):
        """Broad-phase candidates of the linear sweep x0 → x1, boxes inflated by d̂: every pair that comes
        within d̂ anywhere on the segment is in the set. Used for CCD and the line-search trials' collision sets
        (the compiled barrier returns (fv, ee) arrays, the ipctk barrier ipctk ``Candidates``). ``moving_only``
        (compiled barrier; for CCD alone, not for energies along the sweep): also leave out the pairs whose
        vertices all stay where they are (x0 = x1), which cannot collide — unless an obstacle vertex moves (the
        broad phase never pairs two obstacle vertices, so a moving tool is found only against body vertices
        counted as moving)."""
        if self.compiled:
            v0, v1 = self.surface_positions(x0), self.surface_positions(x1)
            if not moving_only:
                return self._candidates(v0, v1)
            still = np.all(v0 == v1, axis=1)
            if not still[self.num_dynamic_collision_vertices :].all():
                return self._candidates(v0, v1)
            if self._still is not None:
                still |= self._still
            return self._candidates(v0, v1, still=still)
        cand = ipctk.Candidates()
        with one_ipctk_thread():
            cand.build(self.mesh, self.surface_positions(x0), self.surface_positions(x1), self.dhat, self.broad_phase())
        return cand

    def potential(self, kappa: float | None = None):
        k = self.kappa if kappa is None else kappa
        if self._potential_cache is None or self._potential_cache[0] != k:
            self._potential_cache = (k, ipctk.BarrierPotential(self.dhat, k))
        return self._potential_cache[1]

    def value(self, ev: ContactEvaluation) -> float:
        if ev.num_active == 0 or self.kappa == 0.0:
            return 0.0
        if self.compiled:
            return self._cb.barrier_value(ev.collisions, ev.surface_positions, self.dhat, self.kappa)
        with one_ipctk_thread():
            return float(self.potential()(ev.collisions, self.mesh, ev.surface_positions))

    def gradient(self, ev: ContactEvaluation, kappa: float | None = None) -> np.ndarray:
        """Gradient on collision-mesh DOFs (interleaved)."""
        if ev.num_active == 0:
            return np.zeros(ev.surface_positions.size)
        if self.compiled:
            return self._cb.barrier_gradient(
                ev.collisions, ev.surface_positions, self.dhat, self.kappa if kappa is None else kappa
            )
        with one_ipctk_thread():
            return np.asarray(self.potential(kappa).gradient(ev.collisions, self.mesh, ev.surface_positions))

    def hessian(self, ev: ContactEvaluation, project: bool = True) -> sp.csc_matrix:
        """Hessian on collision-mesh DOFs; ``project`` clamps each collision's eigenvalues at 0 (PSD)."""
        n = ev.surface_positions.size
        if ev.num_active == 0 or self.kappa == 0.0:
            return sp.csc_matrix((n, n))
        if self.compiled:
            bv, blocks = self.hessian_blocks(ev, np.arange(ev.surface_positions.shape[0]), project)
            rows, cols, vals = self._cb.blocks_to_coo(bv, blocks, self.dim)
            return sp.csc_matrix((vals, (rows, cols)), shape=(n, n))
        method = ipctk.PSDProjectionMethod.CLAMP if project else ipctk.PSDProjectionMethod.NONE
        with one_ipctk_thread():
            return self.potential().hessian(ev.collisions, self.mesh, ev.surface_positions, method)

    def hessian_blocks(self, ev: ContactEvaluation, vertex_map: np.ndarray, project: bool = True):
        """Compiled barrier only: per-collision Hessian blocks restricted to the vertices with
        ``vertex_map`` ≥ 0 (collision-mesh vertex → output vertex id), each projected to PSD after the
        restriction; see :func:`idp.contact.compiled_barrier.barrier_hessian_blocks`."""
        return self._cb.barrier_hessian_blocks(
            ev.collisions, ev.surface_positions, self.dhat, self.kappa, vertex_map, project
        )

    def hessian_block_stream(
        self,
        ev: ContactEvaluation,
        vertex_map: np.ndarray,
        lookahead: tuple[float, float, Any] | None = None,
    ) -> HessianBlockStream:
        """Compiled barrier only: the projected Hessian blocks of :meth:`hessian_blocks`, to be computed a range of
        collisions at a time by whoever adds them into a matrix (:class:`HessianBlockStream`), never all at once.

        ``lookahead`` = (reach, stiffness, candidates): after them, the PSD blocks of a look-ahead barrier with
        activation distance reach·d̂ and stiffness stiffness·κ over the ``candidates`` (fv, ee) within that distance
        at ``ev``'s positions, restricted the same way. Added to a Newton matrix the look-ahead blocks make a
        majorant that sees pairs just outside d̂ (:class:`idp.solver.newton.StepSolver`, ``contact_lookahead``,
        which passes the sweep of the move CCD last cut short: the pairs the direction ran into); never part of
        the energy."""
        if not self.compiled:
            raise RuntimeError("Hessian block streams need the compiled barrier")
        vs = ev.surface_positions
        sets = [(ev.collisions, self.dhat, self.kappa)]
        if lookahead is not None:
            reach, stiffness, candidates = lookahead
            if self.kappa != 0.0 and candidates is not None:
                fv, ee = candidates
                ahead = self._cb.build_collision_set(
                    vs, self._edges, self._faces, fv, ee, reach * self.dhat, self._edge_rest_len2
                )
                if len(ahead):
                    sets.append((ahead, reach * self.dhat, stiffness * self.kappa))
        return HessianBlockStream(self._cb, sets, vs, vertex_map)

    def min_distance(self, ev: ContactEvaluation) -> float:
        """Smallest distance among active pairs (not squared); ``inf`` when no pair is within d̂."""
        if ev.num_active == 0:
            return float("inf")
        if self.compiled:
            return float(np.sqrt(max(self._cb.minimum_sqdist(ev.collisions), 0.0)))
        collisions = cast("ipctk.NormalCollisions", ev.collisions)  # not compiled: ipctk built the collisions
        return float(np.sqrt(max(collisions.compute_minimum_distance(self.mesh, ev.surface_positions), 0.0)))

    def kappa_distance(self, ev: ContactEvaluation) -> float:
        """The distance IPC's adaptive κ watches: :meth:`min_distance` over the pairs that touch no vertex of a
        preserved input crossing (:meth:`exempt_from_kappa`). Around a preserved crossing the barrier is what
        keeps the crossing from spreading, so pairs there are squeezed by design (the mannequin: to 1e-13); were κ
        doubled for them, every one of the ~464,000 pairs within d̂ of the surface would be pushed apart 100 times
        harder (measured: the repair's deviation grew from 0.015 to 0.037 over 37 frames). The ipctk barrier path
        (2D, ``barrier = "ipctk"``) keeps the global minimum."""
        if self._kappa_exempt is None or ev.num_active == 0 or not self.compiled:
            return self.min_distance(ev)
        cs = ev.collisions
        verts = np.asarray(cs.verts)
        exempt = np.zeros(verts.shape[0], dtype=bool)
        for j in range(verts.shape[1]):
            col = verts[:, j]
            exempt |= (col >= 0) & self._kappa_exempt[np.maximum(col, 0)]
        keep = ~exempt
        if not keep.any():
            return float("inf")
        return float(np.sqrt(max(float(np.min(cs.sqdist[keep])), 0.0)))

    def exempt_from_kappa(self, vertices: np.ndarray) -> None:
        """Full-mesh vertex ids whose pairs :meth:`kappa_distance` leaves out (preserved crossings' vertices)."""
        mask = np.zeros(self.to_full.size, dtype=bool)
        cm = self.full_to_collision[np.asarray(vertices, dtype=np.int64)]
        mask[cm[cm >= 0]] = True
        self._kappa_exempt = mask if mask.any() else None

    # -- stiffness ------------------------------------------------------------
    def initialize_kappa(
        self, ev: ContactEvaluation, energy_gradient_collision: np.ndarray, average_mass: float
    ) -> float:
        """IPC initial stiffness (gradient balance, clamped to [κ_min, κ_max]); never lowers the current κ.

        With a user-given κ this only fills in κ_max (100× the given value). With ``kappa_init = "once"`` only the
        first call that sees a pair within d̂ balances (later ones return κ unchanged; the adaptive doubling goes
        on): in an animation repair each step is a new frame whose prescribed head may start far from its targets,
        and balancing there raised κ 25× over 18 frames of Kick, pushing every pair within d̂ apart (the deviation
        from the input 0.015 → 0.032)."""
        if not self.kappa_auto or (self.kappa_init_once and self.kappa_initialized):
            return self.kappa
        if ev.num_active:
            self.kappa_initialized = True
        grad_b = self.gradient(ev, kappa=1.0)
        kappa, kappa_max = ipctk.initial_barrier_stiffness(
            self.bbox_diagonal, self.potential(1.0).barrier, self.dhat, average_mass, energy_gradient_collision, grad_b
        )
        self.kappa = max(self.kappa, float(kappa))
        self.kappa_max = max(self.kappa_max, float(kappa_max))
        return self.kappa

    def update_kappa(self, prev_min_distance: float, min_distance: float) -> float:
        """IPC adaptive update: doubles κ while the minimum distance keeps shrinking below 1e-9·diag."""
        if not self.adaptive_kappa or not np.isfinite(min_distance) or not np.isfinite(prev_min_distance):
            return self.kappa
        self.kappa = float(
            ipctk.update_barrier_stiffness(
                prev_min_distance**2, min_distance**2, self.kappa_max, self.kappa, self.bbox_diagonal
            )
        )
        return self.kappa

    # -- CCD and checks -------------------------------------------------------
    def max_collision_free_step(
        self,
        x0: np.ndarray,
        x1: np.ndarray,
        candidates=None,
        current_min_distance: float | None = np.inf,
        ev: ContactEvaluation | None = None,
    ) -> float:
        """Largest α in [0, 1] such that the linear move x0 → x0 + α(x1 − x0) is collision-free (CCD).

        Tight Inclusion's interval splitting degenerates when a pair is already nearly touching (measured:
        minutes and gigabytes for one query at a 1e-15 gap), so below 1e-4·d̂ the additive CCD is used for that
        query, and the nearly touching pairs are advanced conservatively with exact distances
        (:mod:`idp.contact.near_contact_ccd`; additive CCD alone is not provably conservative there), or, without
        the compiled barrier, by :meth:`_near_pair_step_bound` (2D: the same advancement; 3D: a Lipschitz bound).
        ``current_min_distance``: the smallest gap at x0 that decides this (the Newton loop's active pairs); None:
        the smallest gap among the candidates that move relative to each other (measured here, without building a
        collision set: the feasible moves of step constraints). ``ev``: the collision set at x0 (evaluated here
        when needed and not given).

        With the compiled barrier, ``candidates`` are the (fv, ee) arrays of :meth:`sweep_candidates` (found here
        when not given) and the narrow phase runs only on those that can come close before the step found so far
        (:meth:`_filtered_ccd`); otherwise ipctk's broad phase (or ipctk ``Candidates``) and narrow phase."""
        v0, v1 = self.surface_positions(x0), self.surface_positions(x1)
        if not self.compiled:
            if current_min_distance is None:
                ev = ev if ev is not None else self.evaluate(x0)
                current_min_distance = self.min_distance(ev)
            ccd, near_contact = self._choose_ccd(current_min_distance)
            with one_ipctk_thread():
                if candidates is not None:
                    alpha = float(candidates.compute_collision_free_stepsize(self.mesh, v0, v1, 0.0, ccd))
                else:
                    alpha = float(
                        ipctk.compute_collision_free_stepsize(self.mesh, v0, v1, 0.0, self.broad_phase(), ccd)
                    )
            if near_contact:
                alpha = min(alpha, self._near_pair_step_bound(v0, v1, ev if ev is not None else self.evaluate(x0)))
            return alpha
        from idp.contact import ccd_filter

        if candidates is None:
            candidates = self._candidates(v0, v1)
        fv, ee = candidates
        move = (v0, v1, self._faces, self._edges, fv, ee)
        near_gap = NEAR_CONTACT * self.dhat  # pairs whose boxes are this far apart may skip the exact d(0)
        if current_min_distance is not None:  # the narrow phase is known: bound the candidates with its rescaling
            ccd, near_contact = self._choose_ccd(current_min_distance)
            dist, speed, first, _ = ccd_filter.move_bounds(*move, float(ccd.conservative_rescaling), min_gap=near_gap)
        else:  # known only after d(0): bound for both narrow phases in one pass
            rescalings = (float(self._ccd.conservative_rescaling), float(self._fallback_ccd.conservative_rescaling))
            dist, speed, first, first_fallback = ccd_filter.move_bounds(*move, *rescalings, min_gap=near_gap)
            moving = speed > 0.0
            ccd, near_contact = self._choose_ccd(float(dist[moving].min()) if moving.any() else np.inf)
            if ccd is not self._ccd and first_fallback is not None:  # (asked for: never None here)
                first = first_fallback  # the fallback's own rescaling decides which pairs its narrow phase must see
        bounds = (dist, speed, first)
        alpha = self._filtered_ccd(v0, v1, candidates, ccd, bounds)
        if near_contact:
            from idp.contact.near_contact_ccd import candidate_pairs, conservative_step

            # the candidates closer than 1e-4·d̂ that move relative to each other (d(0) from the CCD bounds)
            near = np.flatnonzero((bounds[0] < NEAR_CONTACT * self.dhat) & (bounds[1] > 0.0))
            pairs, is_pt = candidate_pairs(self._edges, self._faces, fv, ee, near)
            alpha = conservative_step(v0, v1, pairs, is_pt, alpha_max=alpha, keep=NEAR_KEEP)
        return alpha

    def near_contact_step_bound(self, x0: np.ndarray, x1: np.ndarray, current_min_distance: float | None) -> float:
        """An upper bound on the step :meth:`max_collision_free_step` allows for the move x0 → x1, from the pairs
        already closer than 1e-4·d̂ at x0 alone (1.0 when there are none, or without the compiled barrier): their
        conservative advancement is part of that step (it is the min over them and every other pair).

        Why: a Newton direction that moves many vertices far (a prescribed head pulled 10 cm onto its targets)
        sweeps tens of millions of candidate pairs (58 million per call on Kick frame 52, 4 s of bounds alone),
        while a pair squeezed to ~1e-14 lets it advance only ~1e-12 of the way. Shortening the move to this bound
        first, then running the usual CCD on the short move, gives a step that is as safe (the second CCD checks
        every pair of the short sweep) from the pairs within d̂ of the start instead. ``current_min_distance``:
        the smallest gap at x0 (the Newton loop's active pairs); nothing is done unless it is below 1e-4·d̂."""
        if not (self.compiled and self._ccd_name == "tight_inclusion"):
            return 1.0
        if current_min_distance is not None and not current_min_distance < NEAR_CONTACT * self.dhat:
            return 1.0
        from idp.contact.near_contact_ccd import candidate_pairs, conservative_step

        v0, v1 = self.surface_positions(x0), self.surface_positions(x1)
        fv, ee = self._candidates(v0, None)  # pairs within d̂ at x0 (pairs of still vertices left out)
        near = np.flatnonzero(self._candidate_sqdist(v0, fv, ee) < (NEAR_CONTACT * self.dhat) ** 2)
        if near.size == 0:
            return 1.0
        pairs, is_pt = candidate_pairs(self._edges, self._faces, fv, ee, near)
        return float(conservative_step(v0, v1, pairs, is_pt, alpha_max=1.0, keep=NEAR_KEEP))

    def _choose_ccd(self, current_min_distance: float):
        """(narrow phase, near contact): the additive fallback when Tight Inclusion would meet a gap below
        1e-4·d̂ (see :meth:`max_collision_free_step`)."""
        near_contact = self._ccd_name == "tight_inclusion" and current_min_distance < NEAR_CONTACT * self.dhat
        if near_contact:
            self.ccd_fallbacks += 1
            return self._fallback_ccd, True
        return self._ccd, False

    def _filtered_ccd(
        self,
        v0: np.ndarray,
        v1: np.ndarray,
        candidates: tuple[np.ndarray, np.ndarray],
        ccd,
        bounds: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> float:
        """Collision-free step of the move v0 → v1 over the sweep ``candidates`` (fv, ee), with the narrow phase
        ``ccd`` run only on the candidates that can come close before the step found so far
        (:mod:`idp.contact.ccd_filter`; ``bounds`` from its ``move_bounds`` with ``ccd``'s rescaling). Keeps the
        candidates' distance and closing-speed bounds for :meth:`line_search_candidates`."""
        from idp.contact import ccd_filter

        fv, ee = candidates
        rescaling = float(ccd.conservative_rescaling)
        self._move_bounds = (candidates, bounds[0], bounds[1])
        order, first = ccd_filter.ccd_order(bounds[2])
        nf = fv.shape[0]

        def narrow_phase(idx: np.ndarray) -> float:
            alpha = 1.0
            tight = bounds[0][idx] < TIGHT_GAP_SHARE * bounds[1][idx]  # d(0) < share·M: exact advancement
            if tight.any():
                from idp.contact.near_contact_ccd import candidate_pairs, conservative_step

                pairs, is_pt = candidate_pairs(self._edges, self._faces, fv, ee, idx[tight])
                alpha = conservative_step(v0, v1, pairs, is_pt, alpha_max=1.0, keep=1.0 - rescaling)
                idx = idx[~tight]
            if idx.size == 0:
                return alpha
            c = ipctk.Candidates()
            sel = fv[idx[idx < nf]]
            c.fv_candidates = list(map(ipctk.FaceVertexCandidate, sel[:, 0].tolist(), sel[:, 1].tolist()))
            sel = ee[idx[idx >= nf] - nf]
            c.ee_candidates = list(map(ipctk.EdgeEdgeCandidate, sel[:, 0].tolist(), sel[:, 1].tolist()))
            with one_ipctk_thread():
                return min(alpha, float(c.compute_collision_free_stepsize(self.mesh, v0, v1, 0.0, ccd)))

        def refine(idx: np.ndarray, limit: float) -> np.ndarray:
            return ccd_filter.refine(idx, limit, v0, v1, self._faces, self._edges, fv, ee, rescaling, bounds)

        return ccd_filter.narrow_phase_in_order(order, first, narrow_phase, refine)

    def line_search_candidates(self, candidates, fraction: float):
        """The sweep ``candidates`` that can come within d̂ on the first ``fraction`` of the move of the last
        :meth:`max_collision_free_step` that used them (the trial points of a line search bounded by that step);
        ``candidates`` unchanged when that is not known (ipctk barrier, other candidates)."""
        bounds = self._move_bounds
        if bounds is None or bounds[0] is not candidates:
            return candidates
        from idp.contact import ccd_filter

        fv, ee = candidates
        keep = ccd_filter.within(bounds[1], bounds[2], fraction, self.dhat)
        nf = fv.shape[0]
        return fv[keep[:nf]], ee[keep[nf:]]

    def _near_pair_step_bound(self, v0: np.ndarray, v1: np.ndarray, ev: ContactEvaluation) -> float:
        """α keeping every pair closer than 1e-4·d̂ at a safe part of its gap along v0 → v1 (the barrier without
        the compiled 3D path: ipctk's collisions, and every 2D scene).

        Additive CCD is not provably conservative: at gaps of ~1e-10 (squared distances below the rounding of
        the coordinates) it returned α = 1 for a move that crossed (Fig. 3 armadillo, step 104).

        2D: each such point–segment pair is advanced conservatively with exact distances
        (:func:`idp.contact.near_contact_ccd.conservative_step_2d`, keeping ``NEAR_KEEP`` of its gap), so a pair
        that slides along itself costs advances, not step length. (The Lipschitz bound below, used before, froze
        a Fig. 19 disk handle whose vertex slid past its notch at a 1e-8 gap: α ≈ 4e-7 for 30 iterations until the
        handle was reported stalled, where the full step was collision-free.)

        3D: for two primitives with vertices a_i and b_j, every point difference p − q is a convex combination of
        the a_i − b_j, so the gap falls by at most α·max_ij |Δa_i − Δb_j| ≤ α·M, M the largest displacement
        difference between any two of the pair's vertices; α ≤ ½·d/M keeps it above d/2 (relative, not absolute,
        displacements: a common translation costs nothing)."""
        if ev.num_active == 0:
            return 1.0
        limit2 = (NEAR_CONTACT * self.dhat) ** 2
        if self.compiled:
            cs = ev.collisions
            near = np.flatnonzero(cs.sqdist < limit2)
            verts = np.asarray(cs.verts[near], dtype=np.int64)
            sqd = np.asarray(cs.sqdist[near], dtype=float)
        else:
            coll = cast("ipctk.NormalCollisions", ev.collisions)  # not compiled: ipctk built the collisions
            E, F = self.mesh.edges, self.mesh.faces
            rows, dists = [], []
            for i in range(len(coll)):
                c = coll[i]
                d2 = float(c.compute_distance(c.dof(ev.surface_positions, E, F)))
                if d2 < limit2:
                    ids = list(c.vertex_ids(E, F))
                    rows.append(ids + [-1] * (4 - len(ids)))
                    dists.append(d2)
            verts = np.asarray(rows, dtype=np.int64).reshape(-1, 4)
            sqd = np.asarray(dists, dtype=float)
        if verts.shape[0] == 0:
            return 1.0
        if v0.shape[1] == 2:
            from idp.contact.near_contact_ccd import conservative_step_2d

            pairs = verts[:, :3].copy()
            vv = pairs[:, 2] < 0  # vertex–vertex: the "segment" is the second vertex twice
            pairs[vv, 2] = pairs[vv, 1]
            return conservative_step_2d(v0, v1, pairs, alpha_max=1.0, keep=NEAR_KEEP)
        dv = v1 - v0
        moves = np.zeros(verts.shape[0])
        for i in range(4):
            for j in range(i + 1, 4):
                ok = (verts[:, i] >= 0) & (verts[:, j] >= 0)
                diff = dv[verts[ok, i]] - dv[verts[ok, j]]
                moves[ok] = np.maximum(moves[ok], np.sqrt((diff**2).sum(axis=1)))
        moving = moves > 0.0
        if not moving.any():
            return 1.0
        return float(min(1.0, np.min(0.5 * np.sqrt(np.maximum(sqd[moving], 0.0)) / moves[moving])))

    def has_intersections(self, x: np.ndarray) -> bool:
        return bool(ipctk.has_intersections(self.mesh, self.surface_positions(x), self.broad_phase()))
