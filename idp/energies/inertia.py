"""Inertia term ½‖x − x_t‖²_M of the artificial implicit-Euler step (paper eq. 1) and lumped masses."""

from __future__ import annotations

import numpy as np


def lumped_masses(
    num_vertices: int, elements: np.ndarray, volumes: np.ndarray, density: np.ndarray | float
) -> np.ndarray:
    """Per-vertex lumped mass: each element gives density·volume/(d+1) to each of its vertices."""
    per_element = np.broadcast_to(np.asarray(density, dtype=float), volumes.shape) * volumes / elements.shape[1]
    return np.bincount(elements.ravel(), weights=np.repeat(per_element, elements.shape[1]), minlength=num_vertices)


class Inertia:
    """½ (x − x_t)ᵀ M (x − x_t) with a lumped (diagonal) mass matrix M."""

    def __init__(self, masses: np.ndarray, dim: int):
        self.masses = np.asarray(masses, dtype=float)
        self.dim = dim
        self.dof_masses = np.repeat(self.masses, dim)

    def value(self, x: np.ndarray, x_prev: np.ndarray) -> float:
        dx = (x - x_prev).ravel()
        return 0.5 * float(dx @ (self.dof_masses * dx))

    def gradient(self, x: np.ndarray, x_prev: np.ndarray) -> np.ndarray:
        return self.dof_masses * (x - x_prev).ravel()

    def hessian_diagonal(self) -> np.ndarray:
        return self.dof_masses
