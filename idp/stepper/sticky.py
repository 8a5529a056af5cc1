"""Sticky contact: weak springs between close surface vertices of chosen bodies (§7.5 Fig. 21).

Opt-in and **outside the paper's energy**. Two modes (:class:`idp.energies.pair_springs.PairSprings` holds the
springs):

- ``"relink"``: at the start of each step every pair of surface vertices of two *different* chosen bodies within
  ``distance`` is linked by a zero-length spring, (k/2)‖x_a − x_b‖²; links are found afresh from each step's
  start shape, so bodies pulled apart come free and a resumed run relinks exactly as the uninterrupted one.
- ``"glue"`` (the authors' dumplings-on-a-plate run): once, at the start of the first step where any pair lies
  within ``distance``, the pairs are linked by springs whose rest length is their distance then, and the links
  are kept for the rest of the run (checkpointed). Besides pairs of different bodies, a body's own surfaces that
  face each other across a gap — a folded dumpling's seam, whose lips touch but are not joined — are linked, so a
  closed seam stays closed: two vertices of one body are linked when each lies in front of the other's surface
  (outward normals opposed, each on the outer side of the other), which no pair of neighbours on a smooth sheet
  and no pair across a thin wall is.

Pairs come from a k-d tree query and are filtered with array operations (no loop over vertices).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from idp.energies.pair_springs import PairSprings
from idp.mesh.differential import vertex_normals

MODES = ("relink", "glue")


def facing(x: np.ndarray, normals: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Which pairs (a[i], b[i]) face each other: opposed outward normals, and each vertex on the outer side of the
    other's tangent plane."""
    d = x[b] - x[a]
    na, nb = normals[a], normals[b]
    return (
        (np.einsum("ij,ij->i", na, nb) < 0.0)
        & (np.einsum("ij,ij->i", d, na) > 0.0)
        & (np.einsum("ij,ij->i", d, nb) < 0.0)
    )


class StickyContact:
    """Links :attr:`springs` before a step (every step, or once in ``"glue"`` mode); reports links and lengths."""

    report_key = "sticky"

    def __init__(
        self,
        vertices: np.ndarray,
        body_of: np.ndarray,
        distance: float,
        springs: PairSprings,
        mode: str = "relink",
        triangles: np.ndarray | None = None,
    ) -> None:
        """``vertices``: (k,) global ids of the candidate surface vertices; ``body_of``: (k,) the body index of
        each; ``distance``: the link radius in scene units; ``triangles``: the chosen bodies' outward surface
        triangles (global ids), needed in ``"glue"`` mode for the facing test within a body."""
        if not (np.isfinite(distance) and distance > 0.0):
            raise ValueError(f"sticky distance must be positive and finite, got {distance}")
        if mode not in MODES:
            raise ValueError(f"sticky mode must be one of {MODES}, got {mode!r}")
        if mode == "glue" and triangles is None:
            raise ValueError("sticky glue mode needs the bodies' surface triangles")
        self.vertices = np.asarray(vertices, dtype=np.int64)
        self.body_of = np.asarray(body_of, dtype=np.int64)
        self.distance = float(distance)
        self.springs = springs
        self.mode = mode
        self.triangles = None if triangles is None else np.asarray(triangles, dtype=np.int64)
        self.glued_at: int | None = None  # the step whose start shape the glue links were made on

    def candidate_pairs(self, x: np.ndarray) -> np.ndarray:
        """(m, 2) global vertex pairs within ``distance`` that this mode links at ``x``."""
        p = np.asarray(x, dtype=np.float64)
        pairs = cKDTree(p[self.vertices]).query_pairs(self.distance, output_type="ndarray")
        if pairs.shape[0] == 0:
            return np.zeros((0, 2), np.int64)
        other = self.body_of[pairs[:, 0]] != self.body_of[pairs[:, 1]]
        g = self.vertices[pairs]
        if self.mode == "relink":
            return g[other]
        assert self.triangles is not None  # checked in __init__ for glue
        normals = vertex_normals(p, self.triangles, unit=True)
        same = ~other
        keep = other.copy()
        keep[same] = facing(p, normals, g[same, 0], g[same, 1])
        return g[keep]

    def before_step(self, system: Any, step: int, x: np.ndarray) -> None:
        if self.mode == "glue" and self.glued_at is not None:
            return  # the glue holds what it joined
        pairs = self.candidate_pairs(x)
        if self.mode == "relink":
            self.springs.set_pairs(pairs)
            return
        if pairs.shape[0]:
            p = np.asarray(x, dtype=np.float64)
            self.springs.set_pairs(pairs, np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1))
            self.glued_at = int(step)

    def state(self) -> dict[str, np.ndarray]:
        if self.mode != "glue" or self.glued_at is None:
            return {}  # relinked from the start shape of every step: nothing to keep
        return {
            "pairs": self.springs.pairs.copy(),
            "rest_lengths": self.springs.rest_lengths.copy(),
            "glued_at": np.array(self.glued_at),
        }

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        if self.mode == "glue" and "pairs" in st:
            self.springs.set_pairs(st["pairs"], st["rest_lengths"])
            self.glued_at = int(st["glued_at"])

    def report(self, system: Any, x: np.ndarray) -> dict[str, Any]:
        pairs = self.springs.pairs
        lengths = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) if pairs.shape[0] else np.zeros(0)
        out: dict[str, Any] = {
            "links": int(pairs.shape[0]),
            "max_link_length": float(lengths.max()) if lengths.size else 0.0,
            "energy": self.springs.value(x),
        }
        if self.mode == "glue":
            stretch = np.abs(lengths - self.springs.rest_lengths) if lengths.size else np.zeros(0)
            out["max_link_stretch"] = float(stretch.max()) if stretch.size else 0.0
            out["glued_at"] = self.glued_at
        return out
