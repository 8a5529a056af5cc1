"""Plasticity by return mapping on the rest frames (paper §4.5): von Mises in Hencky (log-strain) space.

At the start of a step, for every element with F = Ds Dm⁻¹ = U Σ Vᵀ (det F > 0):

* trial Hencky strain ε = log σ (principal, d values), deviatoric part ε' = ε − mean(ε), and the von Mises
  yield function in stress units f = 2μ‖ε'‖ − (τ_Y + H α), with τ_Y the yield stress, H ≥ 0 the linear
  isotropic hardening modulus and α the element's accumulated plastic strain.  That is, the elastic domain is
  ‖ε'‖ ≤ (τ_Y + H α) / (2μ) in strain units (the Hencky model's Kirchhoff stress deviator is 2μ ε').
* if f > 0 (radial return): Δγ = f / (2μ + H), ε_new = ε − Δγ ε'/‖ε'‖, α ← α + Δγ, so that afterwards
  ‖dev ε_new‖ = (τ_Y + H α_new) / (2μ) exactly: the strain lies on the (hardened) yield surface.  The
  correction only touches the deviatoric part, so tr ε and det F are kept (von Mises flow is isochoric).
* the elastic part is Z(F) = F_e = U exp(ε_new) Vᵀ and the plastic part F_p = F_e⁻¹ F = V exp(ε − ε_new) Vᵀ
  (symmetric, det F_p = 1).  The rest frame takes the plastic part: Dm ← F_p Dm, so that right after the update
  F = Ds Dm⁻¹ = F_e, i.e. the paper's X̄⁻¹ ← X⁻¹ Z(F) with X = Ds, X̄ = Dm.  ``ElasticEnergy.deform_rest_frames``
  stores it in the base frames under any rest transform.

Elements with det F ≤ 0 (possible only for the non-barrier energies) have no log-strain and are skipped.  μ is
the energy's per-element shear modulus from (E, ν).  Everything is vectorised over elements (batched LAPACK SVD).
"""

from __future__ import annotations

import numpy as np

from idp.energies.elastic import ElasticEnergy

#: Relative excess of the yield function below which an element counts as on the surface, not yielding.
_YIELD_RTOL = 1e-12


def _nonnegative_array(value: float | np.ndarray, name: str, strict: bool) -> np.ndarray:
    """``value`` as a float array (scalar or per element), finite and > 0 (``strict``) or ≥ 0, else ValueError."""
    arr = np.array(value, dtype=np.float64)
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a per-element array (m,), got shape {arr.shape}")
    ok = np.isfinite(arr) & ((arr > 0) if strict else (arr >= 0))
    if not np.all(ok):
        bad = arr.reshape(-1)[np.flatnonzero(~ok.reshape(-1))[0]]
        raise ValueError(f"{name} must be finite and {'> 0' if strict else '≥ 0'}, got {bad!r}")
    return arr


class VonMisesPlasticity:
    """Von Mises return mapping with optional linear isotropic hardening, applied to one ``ElasticEnergy``.

    ``yield_stress`` τ_Y (stress units, like Young's modulus) and ``hardening`` H are scalars or per element.
    The object keeps the per-element accumulated plastic strain α (``plastic_strain``, for VTU cell data and
    for hardening); it is sized by the first ``apply`` and belongs to that energy's elements.
    """

    def __init__(self, yield_stress: float | np.ndarray, hardening: float | np.ndarray = 0.0) -> None:
        self.yield_stress = _nonnegative_array(yield_stress, "yield stress", strict=True)
        self.hardening = _nonnegative_array(hardening, "hardening modulus", strict=False)
        #: (m,) accumulated plastic strain α = Σ Δγ per element (None before the first ``apply``).
        self.plastic_strain: np.ndarray | None = None
        #: (m,) bool: elements that yielded in the last ``apply``.
        self.last_yielded: np.ndarray | None = None

    def _per_element(self, arr: np.ndarray, m: int, name: str) -> np.ndarray:
        if arr.ndim == 0:
            return np.full(m, float(arr))
        if arr.shape != (m,):
            raise ValueError(f"{name} has shape {arr.shape} but the energy has {m} elements")
        return arr

    def _state(self, m: int) -> np.ndarray:
        if self.plastic_strain is None:
            self.plastic_strain = np.zeros(m)
        elif self.plastic_strain.shape != (m,):
            raise ValueError(
                f"this plasticity model holds the state of {self.plastic_strain.size} elements, "
                f"the energy has {m}: use one VonMisesPlasticity per body"
            )
        return self.plastic_strain

    def yield_strain(self, energy: ElasticEnergy) -> np.ndarray:
        """(m,) current yield radius in deviatoric Hencky strain, (τ_Y + H α) / (2μ)."""
        m = energy.elements.shape[0]
        alpha = self.plastic_strain if self.plastic_strain is not None else np.zeros(m)
        tau = self._per_element(self.yield_stress, m, "yield stress")
        H = self._per_element(self.hardening, m, "hardening modulus")
        return (tau + H * alpha) / (2.0 * energy.mu)

    def apply(self, energy: ElasticEnergy, x: np.ndarray) -> int:
        """Return-map every element of ``energy`` at positions ``x`` (n,d), update its rest frames and the
        accumulated plastic strain; returns the number of elements that yielded."""
        F = energy.deformation_gradients(x)
        m = F.shape[0]
        alpha = self._state(m)
        tau = self._per_element(self.yield_stress, m, "yield stress")
        H = self._per_element(self.hardening, m, "hardening modulus")
        self.last_yielded = np.zeros(m, dtype=bool)
        if m == 0:
            return 0
        live = np.flatnonzero(np.linalg.det(F) > 0)
        _, sig, Vt = np.linalg.svd(F[live])
        with np.errstate(divide="ignore"):
            eps = np.log(sig)  # −inf only for a numerically rank-deficient F, which then does not yield below
        dev = eps - eps.mean(axis=1, keepdims=True)
        norm = np.sqrt(np.einsum("ij,ij->i", dev, dev))
        mu2 = 2.0 * energy.mu[live]
        f = mu2 * norm - (tau[live] + H[live] * alpha[live])
        # rounding-level excess (an element already on the surface) is not a yield
        hit = np.flatnonzero(np.isfinite(f) & (f > _YIELD_RTOL * (tau[live] + H[live] * alpha[live])))
        if hit.size == 0:
            return 0
        which = live[hit]
        dgamma = f[hit] / (mu2[hit] + H[which])
        # F_p = V exp(Δγ n) Vᵀ with the flow direction n = ε'/‖ε'‖ (ε − ε_new = Δγ n)
        flow = np.exp(dgamma[:, None] * dev[hit] / norm[hit, None])
        V = np.transpose(Vt[hit], (0, 2, 1))
        Fp = (V * flow[:, None, :]) @ Vt[hit]
        energy.deform_rest_frames(Fp, which)
        alpha[which] += dgamma
        self.last_yielded[which] = True
        return int(which.size)
