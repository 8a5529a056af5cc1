"""Vertex selections for handles and fixed sets: boxes, spheres and index lists, absolute or relative.

Relative coordinates are fractions of the bounding box of the positions the selection is evaluated on
(0 = min, 1 = max per axis): the rest placement, or the current shape when a handle is selected at a later
step (paper §7.1: the bar's third handle is chosen on the deformed shape at frame 26).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idp.mesh.placement import select_in_box


def _relative_point(p: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return (1.0 - p) * lo + p * hi


@dataclass
class Selection:
    """One of: ``box`` = (lo, hi); ``sphere`` = (centre, radius); ``indices``; ``everything`` — minus the
    vertices ``exclude`` selects (evaluated on the same positions)."""

    box: tuple[np.ndarray, np.ndarray] | None = None
    sphere: tuple[np.ndarray, float] | None = None
    indices: np.ndarray | None = None
    everything: bool = False
    relative: bool = False
    exclude: Selection | None = None

    def select(self, vertices: np.ndarray) -> np.ndarray:
        """Sorted local vertex indices (int64) selected among ``vertices`` (n, d)."""
        chosen = self._select_base(vertices)
        if self.exclude is None:
            return chosen
        return np.setdiff1d(chosen, self.exclude.select(vertices), assume_unique=True).astype(np.int64)

    def _select_base(self, vertices: np.ndarray) -> np.ndarray:
        v = np.asarray(vertices, dtype=float)
        n = v.shape[0]
        if self.everything:
            return np.arange(n, dtype=np.int64)
        if self.indices is not None:
            idx = np.unique(np.asarray(self.indices, dtype=np.int64))
            if idx.size and (idx[0] < 0 or idx[-1] >= n):
                bad = int(idx[-1] if idx[-1] >= n else idx[0])
                raise IndexError(f"index {bad} out of range (the mesh has {n} vertices)")
            return idx
        if self.box is not None:
            rel = (v.min(axis=0), v.max(axis=0)) if self.relative else None
            return select_in_box(v, self.box[0], self.box[1], relative_to=rel)
        if self.sphere is not None:
            c = np.asarray(self.sphere[0], dtype=float)
            if self.relative:
                c = _relative_point(c, v)
            return np.flatnonzero(np.linalg.norm(v - c, axis=1) <= self.sphere[1]).astype(np.int64)
        raise ValueError("empty selection: give a box, a sphere, indices or everything")
