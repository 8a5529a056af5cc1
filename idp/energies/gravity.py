"""Gravity as a potential energy (paper §7.5 modeling scenes: dumplings dropped on a plate, flowers in a vase).

E_g(x) = −Σ_i m_i g·x_i with the lumped masses m_i of the system (zero on obstacle vertices, so obstacles
do not fall). It is linear in x: its gradient is the constant −m ⊗ g and its Hessian is zero, so it joins
the System's ``linear_terms`` (value and gradient only) and the step energy ½‖x − xᵗ‖²_M + h(E + E_g) moves
an unobstructed body at rest by exactly h·g per step.
"""

from __future__ import annotations

import numpy as np


class GravityPotential:
    """Linear term −Σ_i m_i g·x_i over every vertex with a mass."""

    def __init__(self, masses: np.ndarray, gravity: np.ndarray) -> None:
        m = np.asarray(masses, dtype=np.float64).reshape(-1)
        g = np.asarray(gravity, dtype=np.float64).reshape(-1)
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(g))):
            raise ValueError("gravity and masses must be finite")
        self.gravity = g
        self.num_vertices = m.size
        self._force = np.ascontiguousarray((m[:, None] * g[None, :]).reshape(-1))  # m_i g, flattened (n·d,)

    def set_masses(self, masses: np.ndarray) -> None:
        """Follow a change of the lumped masses (the weight is m_i g)."""
        m = np.asarray(masses, dtype=np.float64).reshape(-1)
        self._force = np.ascontiguousarray((m[:, None] * self.gravity[None, :]).reshape(-1))

    def value(self, x: np.ndarray) -> float:
        """−Σ m_i g·x_i."""
        return -float(self._force @ np.asarray(x, dtype=np.float64).reshape(-1))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """−m ⊗ g (a fresh array: the caller may add to it)."""
        return -self._force
