"""Sticky contact: weak springs between close surface vertices of chosen bodies, relinked every step (§7.5 Fig. 21).

Opt-in and **outside the paper's energy** (the authors' dumplings-on-a-plate run adds such springs between the
wrappers and the pusher). At the start of each step the condition links every pair of surface vertices of two
*different* chosen bodies that lie within ``distance`` of each other (a k-d tree query, no loop over vertices),
and the step energy holds (k/2)‖x_a − x_b‖² per link (:class:`idp.energies.pair_springs.PairSprings`). Links are
found afresh from each step's start shape, so a resumed run relinks exactly as the uninterrupted one.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from idp.energies.pair_springs import PairSprings


class StickyContact:
    """Relinks :attr:`springs` before every step; reports the number of links and their longest length."""

    report_key = "sticky"

    def __init__(self, vertices: np.ndarray, body_of: np.ndarray, distance: float, springs: PairSprings) -> None:
        """``vertices``: (k,) global ids of the candidate surface vertices; ``body_of``: (k,) the body index of
        each (links join different bodies only); ``distance``: the link radius in scene units."""
        if not (np.isfinite(distance) and distance > 0.0):
            raise ValueError(f"sticky distance must be positive and finite, got {distance}")
        self.vertices = np.asarray(vertices, dtype=np.int64)
        self.body_of = np.asarray(body_of, dtype=np.int64)
        self.distance = float(distance)
        self.springs = springs

    def before_step(self, system: Any, step: int, x: np.ndarray) -> None:
        p = np.asarray(x, dtype=np.float64)[self.vertices]
        pairs = cKDTree(p).query_pairs(self.distance, output_type="ndarray")
        if pairs.shape[0]:
            pairs = pairs[self.body_of[pairs[:, 0]] != self.body_of[pairs[:, 1]]]
        self.springs.set_pairs(self.vertices[pairs] if pairs.shape[0] else np.zeros((0, 2), np.int64))

    def report(self, system: Any, x: np.ndarray) -> dict[str, Any]:
        pairs = self.springs.pairs
        lengths = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) if pairs.shape[0] else np.zeros(0)
        return {
            "links": int(pairs.shape[0]),
            "max_link_length": float(lengths.max()) if lengths.size else 0.0,
            "energy": self.springs.value(x),
        }
