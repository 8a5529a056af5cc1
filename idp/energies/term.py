"""The seam every energy plugs into: what the Newton loop asks of an element energy term.

The step energy is S(x) = ½‖x − x_t‖²_M + h·Σ_terms w·E_term(x) + B(x) (+ per-step penalties). An element
term is a sum of per-element (per-stencil) contributions over a fixed set of global DOF stencils: elastic
energies on tets/triangles, shell membrane on triangles, bending on hinges, a Laplacian smoothing term, ...
The assembler builds the sparse pattern once from ``element_dofs()``; the Newton loop streams the
PSD-projected element Hessians into it and takes the minimum of the terms' ``max_step`` bounds in the line
search. Nothing in the Newton loop depends on which kind of term it is.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

#: ``sink(first, blocks)``: receives the (g, k, k) Hessian blocks of elements first … first+g−1.
HessianSink = Callable[[int, np.ndarray], None]


@runtime_checkable
class ElementTerm(Protocol):
    """An energy E(x) = Σ_e E_e(x[stencil_e]) over fixed DOF stencils (see the module docstring).

    ``x`` is the full (n, d) position array; gradients are flat (n·d,) in interleaved vertex order."""

    def element_dofs(self) -> np.ndarray:
        """(m, k) global DOF indices (vertex·d + coordinate) of each stencil, vertex-major."""
        ...

    def value(self, x: np.ndarray) -> float:
        """Total energy; +inf where the state is infeasible for this term (e.g. an inverted element)."""
        ...

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·d,) gradient."""
        ...

    def value_gradient_hessian_groups(
        self, x: np.ndarray, sink: HessianSink, project: bool = True, group: int = 4096
    ) -> tuple[float, np.ndarray]:
        """(energy, flat gradient); stencil Hessians (PSD-projected if ``project``) handed to ``sink`` in groups."""
        ...


def max_step(term: object, x: np.ndarray, direction: np.ndarray) -> float:
    """The largest α ∈ [0, 1] for which ``term`` stays feasible along x + α·direction (1 when it has no bound).

    Terms that guard a feasibility condition (a barrier elastic energy and element inversion) implement
    ``max_step(x, direction)``; the others have no bound."""
    bound = getattr(term, "max_step", None)
    return 1.0 if bound is None else float(bound(x, direction))
