"""Central finite differences shared by the energy tests (step EPS per coordinate)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

EPS = 1e-6


def fd_gradient(f: Callable[[np.ndarray], float], x: np.ndarray) -> np.ndarray:
    """(x.size,) central differences of the scalar f at x (any shape)."""
    g = np.zeros(x.size)
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = EPS
        d = e.reshape(x.shape)
        g[i] = (f(x + d) - f(x - d)) / (2 * EPS)
    return g


def fd_hessian(grad: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    """(x.size, x.size) central differences of the gradient ``grad`` at x."""
    H = np.zeros((x.size, x.size))
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = EPS
        d = e.reshape(x.shape)
        H[:, i] = (grad(x + d) - grad(x - d)) / (2 * EPS)
    return H
