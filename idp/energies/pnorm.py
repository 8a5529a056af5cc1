"""The p-norm extension of a distortion energy for min-max distortion (paper §7.4, eq. 9).

E_p(x) = r(p) Σ_t v_t Ψ̂(F_t)^p, r(p) = Ψ̂(I)^{1−p} / p, over the base distortion Ψ̂ in its unshifted classical
form — symmetric Dirichlet w(‖F‖² + ‖F⁻¹‖²) or neo-Hookean — so that elements with larger distortion weigh more
and, as p grows, minimising E_p approaches min_x max_t Ψ(F_t).  r(p) makes the stress at the rest shape and its
derivative (the Hessian there) equal to the base energy's, so material parameters keep their meaning.

The energy is the same element term as :class:`~idp.energies.elastic.ElasticEnergy` (value, gradient, Hessian
through the analytic singular-value eigensystem with its exact per-element PSD projection, inversion filter as
the step bound, rest-shape operations) with the exponent passed to the compiled kernel; the scalar chain rule and
the overflow-free continuation for large p are in :mod:`idp.energies._pnorm_kernels`.
"""

from __future__ import annotations

import numpy as np

from idp.energies._pnorm_kernels import LOG_CAP
from idp.energies.elastic import ElasticEnergy

#: Base distortions the p-norm extends: the inversion barriers, whose unshifted Ψ̂ is bounded below by Ψ̂(I) > 0.
PNORM_MODELS = ("symmetric_dirichlet", "neo_hookean")


class PNormEnergy(ElasticEnergy):
    """E_p = r(p) Σ v Ψ̂^p over a base barrier distortion (``model``: symmetric Dirichlet or neo-Hookean).

    ``power`` p ≥ 1 (p = 1 is the base energy up to a constant).  For neo-Hookean the Poisson ratio must be ≥ 0
    (λ ≥ 0), else Ψ̂ is unbounded below and Ψ̂^p undefined.  The exact ρ^p (ρ = Ψ̂/Ψ̂(I)) is used while
    p ln ρ ≤ ``LOG_CAP``; beyond, a C² quadratic continuation keeps value, gradient and Hessian finite."""

    def __init__(
        self,
        model: str,
        rest_vertices: np.ndarray,
        elements: np.ndarray,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        weight: float | np.ndarray | None = None,
        power: float = 2.0,
    ) -> None:
        if model not in PNORM_MODELS:
            raise ValueError(f"the p-norm extends {' or '.join(PNORM_MODELS)}, not {model!r}")
        p = float(power)
        if not (np.isfinite(p) and p >= 1.0):
            raise ValueError(f"p-norm power must be finite and >= 1, got {power!r}")
        if model == "neo_hookean" and p != 1.0 and np.any(np.asarray(poisson_ratio) < 0):
            raise ValueError("a neo-Hookean p-norm needs poisson_ratio >= 0 (lambda >= 0): Ψ̂ is unbounded below")
        super().__init__(model, rest_vertices, elements, youngs_modulus, poisson_ratio, weight)
        self.power = p

    def rest_distortion(self) -> np.ndarray:
        """Ψ̂(I) per element (m,): 2 d w for symmetric Dirichlet, μ d / 2 for neo-Hookean."""
        if self.model == "symmetric_dirichlet":
            return 2.0 * self.dim * self.weight
        return 0.5 * self.dim * self.mu

    @property
    def exact_ratio_limit(self) -> float:
        """ρ_c: up to this distortion ratio Ψ̂/Ψ̂(I) the energy is exactly eq. 9 (beyond, its quadratic tail)."""
        return float(np.exp(LOG_CAP / self.power))
