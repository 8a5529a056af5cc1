"""St. Venant-Kirchhoff membrane energy of a triangle mesh in 3D (thin shells, paper §7.2).

Per triangle t with rest metric Ā_t (2x2 first fundamental form of the rest edges e1 = x1 - x0,
e2 = x2 - x0: Ā_ij = ē_i·ē_j), current metric A_t and Green strain E_t = ½ Ā_t⁻¹ (A_t - Ā_t):

    W = Σ_t ā_t h_t (μ_t tr(E_t²) + λ_t/2 (tr E_t)²),

ā_t the rest area, h_t the thickness, μ = Y/(2(1+ν)) and the *plane-stress* Lamé parameter
λ = Y ν/(1 - ν²) (= 2μλ₃/(λ₃ + 2μ), the 3D λ₃ with the normal stress eliminated), Y Young's modulus
and ν Poisson's ratio.  Non-barrier (finite for every state, degenerate triangles included);
zero with zero gradient at the rest shape and invariant under rigid motions.  Exact 9x9 Hessians,
PSD-projected per triangle on request.  ``set_rest_shape`` only recomputes the (m,2,2) metrics and
areas (vectorised numpy), so the animation repair can change the rest shape every step.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from idp.energies import _membrane_kernels as _k
from idp.energies._stencil_term import StencilTerm, per_item, positions, vertex_dofs


def membrane_lame(
    youngs_modulus: float | np.ndarray, poisson_ratio: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(μ, plane-stress λ) = (Y/(2(1+ν)), Yν/(1-ν²)) for Y > 0 and -1 < ν ≤ 0.5 (arrays)."""
    Y = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    if not np.all(np.isfinite(Y) & (Y > 0)):
        raise ValueError(f"youngs_modulus must be finite and > 0, got {youngs_modulus!r}")
    if not np.all((nu > -1.0) & (nu <= 0.5)):
        raise ValueError(f"poisson_ratio must lie in (-1, 0.5], got {poisson_ratio!r}")
    return Y / (2.0 * (1.0 + nu)), Y * nu / (1.0 - nu * nu)


def rest_metrics(rest_vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Ā (m,2,2), Ā⁻¹ (m,2,2), rest areas (m,)); ValueError naming the first degenerate triangle."""
    X = np.asarray(rest_vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    xe = X[T]
    D = np.stack([xe[:, 1] - xe[:, 0], xe[:, 2] - xe[:, 0]], axis=2)  # (m,3,2)
    A = np.einsum("mci,mcj->mij", D, D)
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    scale = np.maximum(A[:, 0, 0] * A[:, 1, 1], np.finfo(float).tiny)
    bad = np.flatnonzero(~(det > 1e-14 * scale))
    if bad.size:
        t = int(bad[0])
        raise ValueError(f"triangle {t} (vertices {T[t].tolist()}) is degenerate in the rest shape")
    inv = np.empty_like(A)
    inv[:, 0, 0] = A[:, 1, 1] / det
    inv[:, 1, 1] = A[:, 0, 0] / det
    inv[:, 0, 1] = -A[:, 0, 1] / det
    inv[:, 1, 0] = -A[:, 1, 0] / det
    return np.ascontiguousarray(A), np.ascontiguousarray(inv), 0.5 * np.sqrt(det)


class MembraneEnergy(StencilTerm):
    """StVK membrane W = Σ_t ā_t h_t (μ tr(E²) + λ/2 (tr E)²) over ``triangles`` (m,3) of the global mesh.

    Material (Young's modulus, Poisson ratio, thickness) scalars or per triangle; see the module
    docstring for the formula and the plane-stress λ.  Implements ``ElementTerm`` (9x9 blocks)."""

    def __init__(
        self,
        rest_vertices: np.ndarray,
        triangles: npt.ArrayLike,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        thickness: float | np.ndarray,
    ) -> None:
        X = np.asarray(rest_vertices, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3:
            raise ValueError(f"rest_vertices must be (n, 3), got shape {X.shape}")
        T = np.asarray(triangles, dtype=np.int64)
        if T.ndim != 2 or T.shape[1] != 3:
            raise ValueError(f"triangles must be (m, 3), got shape {T.shape}")
        if T.size and (T.min() < 0 or T.max() >= X.shape[0]):
            raise ValueError(f"triangles index vertices outside [0, {X.shape[0]})")
        self.triangles = np.ascontiguousarray(T)
        self.num_vertices = X.shape[0]
        self._dofs = vertex_dofs(self.triangles)
        self.set_material(youngs_modulus, poisson_ratio, thickness)
        self.set_rest_shape(X)

    def set_material(
        self, youngs_modulus: float | np.ndarray, poisson_ratio: float | np.ndarray, thickness: float | np.ndarray
    ) -> None:
        """(Re)set Young's modulus, Poisson ratio and thickness (scalars or per triangle)."""
        m = self.triangles.shape[0]
        mu, lam = membrane_lame(
            per_item(youngs_modulus, m, "youngs_modulus"), per_item(poisson_ratio, m, "poisson_ratio")
        )
        h = per_item(thickness, m, "thickness")
        if not np.all(np.isfinite(h) & (h > 0)):
            raise ValueError(f"thickness must be finite and > 0, got {thickness!r}")
        self.mu, self.lam, self.thickness = np.ascontiguousarray(mu), np.ascontiguousarray(lam), h
        if hasattr(self, "rest_areas"):
            self._weight = np.ascontiguousarray(self.rest_areas * self.thickness)

    def set_rest_shape(self, rest_vertices: np.ndarray) -> None:
        """Rest metrics Ā and rest areas from ``rest_vertices`` (n,3); vectorised, O(m)."""
        X = positions(rest_vertices, self.num_vertices)
        self.rest_metric, self.rest_metric_inv, self.rest_areas = rest_metrics(X, self.triangles)
        self._weight = np.ascontiguousarray(self.rest_areas * self.thickness)

    def green_strains(self, x: np.ndarray) -> np.ndarray:
        """(m,2,2) E = ½ Ā⁻¹ (A - Ā) (in the rest edge basis; not symmetric in general)."""
        xe = positions(x, self.num_vertices)[self.triangles]
        D = np.stack([xe[:, 1] - xe[:, 0], xe[:, 2] - xe[:, 0]], axis=2)
        A = np.einsum("mci,mcj->mij", D, D)
        return 0.5 * self.rest_metric_inv @ (A - self.rest_metric)

    def _kernel(
        self,
        x: np.ndarray,
        first: int,
        last: int,
        want_grad: bool,
        want_hess: bool,
        project: bool,
        e: np.ndarray,
        g: np.ndarray,
        h: np.ndarray,
    ) -> None:
        _k.membrane_terms(
            x,
            self.triangles[first:last],
            self.rest_metric[first:last],
            self.rest_metric_inv[first:last],
            self._weight[first:last],
            self.mu[first:last],
            self.lam[first:last],
            want_grad,
            want_hess,
            project,
            e,
            g,
            h,
        )
