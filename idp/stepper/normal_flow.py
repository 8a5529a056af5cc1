"""Normal flow (paper §7.2) as a per-step condition: E(x, Nᵗ) = B(x) − γ ½ xᵀLx − β xᵀNᵗ.

The smoothing −γ ½ xᵀLx is an element term (:class:`idp.mesh.differential.LaplacianSmoothing`) and the push
−β xᵀNᵗ a linear term (:class:`idp.mesh.differential.NormalForce`); both sit in the System like any energy, so
the flow runs on the shared Newton loop, CCD line search and certificate. This condition only does what
changes per step:

* ``before_step``: Nᵗ from the surface at the start of the step (``mass``: Nᵢ = mᵢ n̂ᵢ with the masses of M, so an
  unobstructed, unsmoothed step moves every vertex by β n̂ᵢ); when asked (negative flows, by default), the
  lumped masses M and the Laplacian's weights are rebuilt from the current shape too (the paper does this for
  smoother inward sequences);
* ``report``: enclosed volume (closed shells) or area, its ratio to the input, and the surface area.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idp.mesh.differential import (
    LaplacianSmoothing,
    NormalForce,
    face_area_normals,
    vertex_areas,
    vertex_normals,
)
from idp.mesh.surface import enclosed_volume


class NormalFlow:
    """The per-step part of a normal flow over the shell triangles ``faces`` (global vertex ids)."""

    report_key = "flow"

    def __init__(
        self,
        x: np.ndarray,
        faces: np.ndarray,
        *,
        beta: float,
        gamma: float,
        laplacian: str = "area",
        normals: str = "mass",
        recompute_every_step: bool = False,
        mass_per_area: np.ndarray | float = 1.0,
        closed: bool = True,
    ) -> None:
        """``x``: (n,3) start positions of the whole system; ``mass_per_area``: density × thickness (per vertex
        or one value), used when the masses follow the shape; ``closed``: report enclosed volume (else area)."""
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.num_vertices = int(x.shape[0])
        self.beta, self.gamma = float(beta), float(gamma)
        self.recompute_every_step = bool(recompute_every_step)
        self.mass_per_area = mass_per_area
        self.closed = bool(closed)
        self.vertices = np.unique(self.faces)
        self.smoothing = LaplacianSmoothing(x, self.faces, self.gamma, weights=laplacian)
        self.normals = normals
        self.force = NormalForce(
            self.faces, self.num_vertices, self.beta, weighting="lumped_unit" if normals == "mass" else normals
        )
        self.initial_volume = self._volume(x)
        self.initial_area = self._area(x)

    def _area(self, x: np.ndarray) -> float:
        return float(np.linalg.norm(face_area_normals(x, self.faces), axis=1).sum())

    def _volume(self, x: np.ndarray) -> float | None:
        return float(enclosed_volume(x, self.faces)) if self.closed else None

    def before_step(self, system: Any, step: int, x: np.ndarray) -> None:
        if self.recompute_every_step and step > 1:
            self.smoothing.set_weights(x)
            masses = system.masses.copy()
            masses[self.vertices] = (self.mass_per_area * vertex_areas(x, self.faces))[self.vertices]
            system.set_masses(masses)
        if self.normals == "mass":
            # Nᵢ = mᵢ n̂ᵢ with mᵢ the mass in M (not the current area), as the authors' force: the push is then
            # β n̂ at every vertex whatever its share of area.  Current areas against masses frozen at the start
            # ("lumped_unit") let a vertex whose triangles grew (from 1e-7 to 1e-3 on the cat) take a push 10⁴
            # times its inertia and fly off.
            unit = vertex_normals(x, self.faces, unit=True)
            self.force.set_normals(np.asarray(system.masses, dtype=float)[:, None] * unit)
        else:
            self.force.update(x)

    def report(self, system: Any, x: np.ndarray) -> dict:
        vol, area = self._volume(x), self._area(x)
        return {
            "volume": vol,
            "volume_ratio": vol / self.initial_volume if vol is not None and self.initial_volume else None,
            "area": area,
            "area_ratio": area / self.initial_area if self.initial_area else None,
        }
