"""Distortion measures of a deformation, as the paper reports them (§7.4): Ψ_SD per element and its summary."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def symmetric_dirichlet_distortion(F: np.ndarray) -> np.ndarray:
    """Ψ_SD = ‖F‖²_F + ‖F⁻¹‖²_F per element (m,) for F (m, d, d): the distortion the paper reports (2d is an
    isometry: 4 for triangles, 6 for tets); +inf where det F ≤ 0."""
    F = np.asarray(F, dtype=np.float64)
    out = np.full(F.shape[0], np.inf)
    if F.shape[0] == 0:
        return out
    ok = np.linalg.det(F) > 0
    Fi = np.linalg.inv(F[ok])
    out[ok] = np.einsum("mij,mij->m", F[ok], F[ok]) + np.einsum("mij,mij->m", Fi, Fi)
    return out


def _quantile(sorted_psi: np.ndarray, q: float) -> float:
    """Linear-interpolation quantile (numpy's default) that stays +∞ rather than NaN next to infinite values."""
    pos = q * (sorted_psi.size - 1)
    lo, hi = math.floor(pos), math.ceil(pos)
    a, b = float(sorted_psi[lo]), float(sorted_psi[hi])
    if lo == hi or a == b:
        return a
    if math.isinf(b):
        return math.inf
    return a + (b - a) * (pos - lo)


def distortion_summary(psi: np.ndarray, areas: np.ndarray) -> dict[str, Any]:
    """``worst`` (max), ``p99`` and ``median`` over the triangles, ``mean`` weighted by the 3D ``areas``,
    ``count`` (triangles) and ``infinite`` (triangles with Ψ = +∞, i.e. flipped or collapsed)."""
    psi = np.asarray(psi, dtype=np.float64)
    w = np.asarray(areas, dtype=np.float64)
    if psi.size == 0:
        return {"worst": None, "p99": None, "mean": None, "median": None, "count": 0, "infinite": 0}
    s = np.sort(psi)
    infinite = int(np.isinf(psi).sum())
    mean = math.inf if infinite else float((psi * w).sum() / w.sum())
    return {
        "worst": float(s[-1]),
        "p99": _quantile(s, 0.99),
        "mean": mean,
        "median": _quantile(s, 0.5),
        "count": int(psi.size),
        "infinite": infinite,
    }
