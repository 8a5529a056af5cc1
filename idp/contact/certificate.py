"""Independent per-frame certificate: no intersecting surface pairs, no inverted elements, min distance.

It owns its own ipctk collision mesh (built separately from the solver's, without the solver's
static-obstacle shortcut) so a solver bug cannot hide from it: the intersection test is ipctk's. The minimum
distance it reports (not part of the pass/fail) is, in 3D, the smallest exact distance over the compiled broad
phase's pairs of that mesh, obstacle pairs included; ipctk's collision set gives the same number at about twice
the cost (its own LBVH and collision objects, once per frame). When the input had intersections that
the user asked to preserve (paper §5.5), the check lists every crossing (edge, triangle) pair and
requires it to be one of the input's pairs: preserved crossings may stay, no new one may appear.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import ipctk
import numpy as np

from idp.mesh.quality import signed_volumes


@dataclass
class Certificate:
    intersection_free: bool
    inversion_free: bool
    num_inverted: int
    min_element_volume: float
    min_distance: float  # smallest surface distance among pairs closer than ``distance_query``; inf if none
    distance_query: float
    preserved_pairs: int  # intersecting input pairs allowed to persist (paper §5.5)
    intersecting_pairs: int = 0  # counted (not a failure) when the scene runs without the barrier
    guards_intersection: bool = True  # False: contact off, intersections are reported, not failed
    guards_inversion: bool = True  # False: a non-barrier energy, inverted elements are reported, not failed
    degenerate_shell_triangles: int = 0  # shells have no inversion guarantee (paper §4.4): reported, not failed
    prescribed_crossing_pairs: int = 0  # crossings among prescribed vertices only (they follow their input): reported

    @property
    def ok(self) -> bool:
        return (self.intersection_free or not self.guards_intersection) and (
            self.inversion_free or not self.guards_inversion
        )

    def describe(self) -> str:
        parts = []
        if not self.intersection_free:
            parts.append(
                "surfaces intersect" + (f" ({self.intersecting_pairs} pairs)" if self.intersecting_pairs else "")
            )
        if not self.inversion_free:
            parts.append(f"{self.num_inverted} inverted element(s), min volume {self.min_element_volume:.3e}")
        if self.prescribed_crossing_pairs:
            parts.append(f"{self.prescribed_crossing_pairs} crossing pair(s) among prescribed vertices (as prescribed)")
        if self.degenerate_shell_triangles:
            parts.append(f"{self.degenerate_shell_triangles} degenerate shell triangle(s) (reported only)")
        return "; ".join(parts) or f"ok (min distance {self.min_distance:.3e})"

    def to_dict(self) -> dict:
        out = asdict(self)
        out["ok"] = self.ok
        return out


class Certifier:
    """Checks a configuration x (n, d) of the whole scene."""

    def __init__(
        self,
        positions: np.ndarray,
        surface: np.ndarray | None,
        element_sets: list[np.ndarray],
        *,
        distance_query: float,
        require_inversion_free: bool = True,
        require_intersection_free: bool = True,
        preserved_pairs: set | None = None,
        shell_faces: np.ndarray | None = None,
        prescribed_vertices: np.ndarray | None = None,
    ):
        """``require_intersection_free=False`` (a scene without the barrier, locally injective only): frames are
        checked and their intersecting (edge, triangle) pairs counted, but intersections do not fail them;
        ``require_inversion_free=False`` (non-barrier energies): inverted elements are counted, not failed;
        ``shell_faces``: triangles of 3D shells, whose degenerate (near zero-area) triangles are counted;
        ``prescribed_vertices``: (n,) bool, a group whose pairs among themselves the solver leaves out (their motion
        is prescribed, :meth:`idp.contact.model.ContactModel.leave_out_pairs_among`): a crossing pair whose every
        vertex is in it is counted, not failed, and its pairs do not enter the minimum distance."""
        self.shell_faces = None if shell_faces is None or not len(shell_faces) else np.asarray(shell_faces, np.int64)
        self.dim = positions.shape[1]
        self.element_sets = element_sets
        self.require_inversion_free = require_inversion_free
        self.require_intersection_free = require_intersection_free
        self.distance_query = float(distance_query)
        self.mesh = None
        self.surface = None if surface is None else np.asarray(surface, dtype=np.int64)
        self.preserved = set(preserved_pairs or ())
        self.prescribed = None if prescribed_vertices is None else np.asarray(prescribed_vertices, dtype=bool)
        if self.prescribed is not None and not self.prescribed.any():
            self.prescribed = None
        self.num_excluded = len(self.preserved)
        if surface is not None and len(surface):
            surface = np.asarray(surface, dtype=np.int32)
            if self.dim == 3:
                faces, edges = surface, ipctk.edges(surface)
            else:
                faces, edges = np.zeros((0, 3), dtype=np.int32), surface
            self.mesh = ipctk.CollisionMesh.build_from_full_mesh(
                np.ascontiguousarray(positions, dtype=float), edges, faces
            )
            self.to_full = np.asarray(self.mesh.to_full_vertex_id(), dtype=np.int64)
            # collision-mesh edges and faces as the compiled broad phase and classification take them
            self._edges = np.ascontiguousarray(self.mesh.edges, dtype=np.int32)
            self._faces = np.ascontiguousarray(self.mesh.faces, dtype=np.int32)

    def _has_intersections(self, vs: np.ndarray) -> bool:
        """Whether some collision-mesh edge crosses a triangle (3D: idp's own grid and float filter with ipctk's
        robust predicate on the pairs it leaves open, :func:`idp.contact.intersections.has_intersections`: 2.0 ms on
        a late bunny_700 frame against 3.9–5.2 ms for ipctk's LBVH ``has_intersections``; 2D: ipctk's)."""
        if self.dim != 3:
            return bool(ipctk.has_intersections(self.mesh, vs, ipctk.LBVH()))
        from idp.contact.intersections import has_intersections

        return has_intersections(vs, self._edges, self._faces)

    def _min_distance(self, vs: np.ndarray) -> float:
        """Smallest surface distance among pairs closer than ``distance_query``; inf if none. 3D: the compiled
        broad phase (every pair of the collision mesh, obstacle pairs included) and exact closest-feature
        distances; 2D: ipctk's collision set."""
        if self.dim != 3:
            c = ipctk.NormalCollisions()
            c.build(self.mesh, vs, self.distance_query, 0.0, ipctk.LBVH())
            return math.sqrt(max(c.compute_minimum_distance(self.mesh, vs), 0.0)) if len(c) else math.inf
        from idp.contact import compiled_barrier
        from idp.contact._broad_phase import surface_candidates

        nv = vs.shape[0]
        group = None if self.prescribed is None else self.prescribed[self.to_full]
        fv, ee = surface_candidates(vs, None, self._edges, self._faces, self.distance_query, nv, None, group)
        n = fv.shape[0] + ee.shape[0]
        if n == 0:
            return math.inf
        sqd = np.empty(n)
        compiled_barrier.classify(
            vs,
            self._faces,
            self._edges,
            fv,
            ee,
            np.zeros(self._edges.shape[0]),  # mollifier thresholds: not needed for a distance
            np.empty(n, np.int64),
            sqd,
            np.empty(n),
        )
        d2 = float(sqd.min())
        return math.sqrt(max(d2, 0.0)) if d2 < self.distance_query**2 else math.inf

    def check(self, x: np.ndarray) -> Certificate:
        if not np.all(np.isfinite(x)):
            return Certificate(False, False, -1, math.nan, math.nan, self.distance_query, self.num_excluded)
        min_vol, n_inv = math.inf, 0
        for el in self.element_sets:
            vols = signed_volumes(x, el)
            if vols.size:
                min_vol = min(min_vol, float(vols.min()))
                n_inv += int(np.count_nonzero(vols <= 0))
        inversion_free = n_inv == 0
        intersection_free, min_d, n_pairs, n_prescribed = True, math.inf, 0, 0
        if self.mesh is not None:
            assert self.surface is not None  # the collision mesh is only built from a surface
            vs = np.ascontiguousarray(x[self.to_full], dtype=float)
            if not self.require_intersection_free:
                from idp.contact.intersections import intersecting_pair_keys

                n_pairs = len(intersecting_pair_keys(x, self.surface))
                intersection_free = n_pairs == 0
            elif self.preserved or self.prescribed is not None:
                from idp.contact.intersections import intersecting_pair_keys, pairs_within

                if self.preserved or self._has_intersections(vs):
                    new = intersecting_pair_keys(x, self.surface) - self.preserved
                    n_prescribed = 0 if self.prescribed is None else pairs_within(new, self.prescribed)
                    intersection_free = n_prescribed == len(new)
            else:
                intersection_free = not self._has_intersections(vs)
            if intersection_free:
                min_d = self._min_distance(vs)
        n_degenerate = 0
        if self.shell_faces is not None:
            from idp.mesh.surface_checks import degenerate_triangles

            n_degenerate = int(degenerate_triangles(x, self.shell_faces).size)
        return Certificate(
            intersection_free,
            inversion_free,
            n_inv,
            min_vol,
            min_d,
            self.distance_query,
            self.num_excluded,
            n_pairs,
            self.require_intersection_free,
            self.require_inversion_free,
            n_degenerate,
            n_prescribed,
        )
