"""Scalar pieces of the p-norm distortion energy (paper §7.4, eq. 9), compiled for the element kernel.

E_p = r(p) Σ_t v_t Ψ̂(F_t)^p with r(p) = Ψ̂(I)^{1−p} / p, where Ψ̂ is the base distortion in its classical,
unshifted form: symmetric Dirichlet Ψ̂ = w (‖F‖² + ‖F⁻¹‖²) (Ψ̂(I) = 2 d w) and neo-Hookean
Ψ̂ = μ/2 ‖F‖² − μ ln J + λ/2 ln² J (Ψ̂(I) = μ d / 2).  idp's kernels evaluate the shifted forms Ψ = Ψ̂ − Ψ̂(I)
(zero at rest), so Ψ̂ = Ψ + Ψ̂(I).  Both are minimal at rotations, Ψ̂ ≥ Ψ̂(I) > 0 (NH needs λ ≥ 0), so the
per-element ratio ρ = Ψ̂ / Ψ̂(I) ≥ 1 and

    v r(p) Ψ̂^p = v Ψ̂(I) g(ρ) / p,   g(ρ) = ρ^p.

With f = Ψ̂(I) g(ρ) / p as a function of the singular values, the chain rule gives f_i = c₁ ψ_i and
f_ij = c₁ ψ_ij + c₂ ψ_i ψ_j with c₁ = g'(ρ)/p and c₂ = g''(ρ)/(p Ψ̂(I)): the stress is the base stress times c₁
(c₁ = 1 at rest, which is what r(p) calibrates), the flip and twist eigenvalues are the base ones times c₁ and
the scaling block gains the rank-one term c₂ ψψᵀ, so the analytic eigensystem (and its exact PSD projection)
carries over unchanged.

**Large p without overflow.** g is ρ^p up to ρ_c with ρ_c^p = e^{LOG_CAP} (≈ 7.7e99) and continues beyond by its
second-order Taylor polynomial at ρ_c (C², increasing, convex).  The energy then stays finite for any base
distortion up to ρ ≈ 1e100 (p = 10: ρ_c = e^23 ≈ 1e10, a stretch of ~1e5), where ρ^p itself would overflow once
p ln ρ > 709 — e.g. a nearly collapsed UV triangle with ρ = 1e40 at p = 10.  Below ρ_c the energy is exactly
eq. 9.
"""

from __future__ import annotations

import math

from idp._leaf import leaf_njit

#: ln of the largest value of ρ^p evaluated exactly; beyond it ρ^p continues by its quadratic Taylor polynomial.
LOG_CAP = 230.0

NEO_HOOKEAN = 0
SYMMETRIC_DIRICHLET = 1


@leaf_njit(error_model="numpy")
def rest_value(model: int, a: float, d: int) -> float:
    """Ψ̂(I) of the unshifted base distortion: SD (a = weight w) 2 d w; NH (a = μ) μ d / 2."""
    if model == SYMMETRIC_DIRICHLET:
        return 2.0 * d * a
    return 0.5 * d * a


@leaf_njit(error_model="numpy")
def power_tail(rho: float, p: float) -> tuple[float, float, float]:
    """(g, g', g'') of g(ρ) = ρ^p, continued by its second-order Taylor polynomial beyond ρ_c = e^{LOG_CAP/p}."""
    lrc = LOG_CAP / p
    if rho > 0.0 and math.log(rho) <= lrc:
        gv = rho**p
        return gv, p * gv / rho, p * (p - 1.0) * gv / (rho * rho)
    rc = math.exp(lrc)
    G = math.exp(LOG_CAP)
    G1 = p * G / rc
    G2 = p * (p - 1.0) * G / (rc * rc)
    u = rho - rc
    return G + G1 * u + 0.5 * G2 * u * u, G1 + G2 * u, G2


@leaf_njit(error_model="numpy")
def sigma_gradient(model: int, a: float, b: float, sig, lnJ: float, d: int, out) -> None:
    """out[i] = ∂Ψ/∂σ_i of the base distortion: SD 2w(σ_i − σ_i⁻³); NH μσ_i − (μ − λ ln J)/σ_i."""
    if model == SYMMETRIC_DIRICHLET:
        for i in range(d):
            s = sig[i]
            out[i] = 2.0 * a * (s - 1.0 / (s * s * s))
    else:
        cc = a - b * lnJ
        for i in range(d):
            out[i] = a * sig[i] - cc / sig[i]
