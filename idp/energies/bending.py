"""Discrete-shell bending energy (Grinspun et al. 2003) on the hinges of a triangle mesh (paper §7.2).

    W = Σ_hinges k_b (θ - θ̄)² |ē|²/h̄,   h̄ = (Ā1 + Ā2)/(3|ē|),  i.e. weight 3|ē|²/(Ā1 + Ā2),

θ the signed dihedral angle (atan2 form, 0 flat, > 0 convex; see ``_bending_kernels``), θ̄, |ē| and the
face areas Ā1, Ā2 from the rest shape, k_b = Y t³/(24(1 - ν²)) × ``multiplier`` (Y Young's modulus,
t thickness, ν Poisson's ratio; scalars or per hinge).  Exact 12x12 Hessians (analytic, see the kernel
docstring), PSD-projected per hinge on request, or their Gauss–Newton part 2c∇θ∇θᵀ (``hessian =
"gauss_newton"``: a tenth of the cost, for shapes that stay near their rest angles, like an animation repair
whose rest shape is the input frame).  δ = θ - θ̄ is not wrapped: a hinge folded through ±π
relative to its rest angle sees the energy jump, as in the original method.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from idp.energies import _bending_kernels as _k
from idp.energies._stencil_term import StencilTerm, per_item, positions, vertex_dofs
from idp.mesh.hinges import triangle_hinges

#: what :class:`BendingEnergy` returns for a PSD Hessian request
BENDING_HESSIANS = ("projected", "gauss_newton")


def bending_stiffness(
    youngs_modulus: float | np.ndarray,
    poisson_ratio: float | np.ndarray,
    thickness: float | np.ndarray,
    multiplier: float | np.ndarray = 1.0,
) -> np.ndarray:
    """k_b = Y t³ / (24 (1 - ν²)) × multiplier (the plate flexural rigidity Y t³/(12(1-ν²)) halved)."""
    Y = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    t = np.asarray(thickness, dtype=np.float64)
    mult = np.asarray(multiplier, dtype=np.float64)
    if not np.all(np.isfinite(Y) & (Y > 0)):
        raise ValueError(f"youngs_modulus must be finite and > 0, got {youngs_modulus!r}")
    if not np.all((nu > -1.0) & (nu <= 0.5)):
        raise ValueError(f"poisson_ratio must lie in (-1, 0.5], got {poisson_ratio!r}")
    if not np.all(np.isfinite(t) & (t > 0)):
        raise ValueError(f"thickness must be finite and > 0, got {thickness!r}")
    if not np.all(np.isfinite(mult) & (mult >= 0)):
        raise ValueError(f"multiplier must be finite and >= 0, got {multiplier!r}")
    return Y * t**3 / (24.0 * (1.0 - nu * nu)) * mult


def dihedral_angles(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """(h,) signed dihedral angles of ``hinges`` (h,4) at positions ``x`` (n,3)."""
    H = np.ascontiguousarray(np.asarray(hinges, dtype=np.int64))
    out = np.empty(H.shape[0])
    if H.shape[0]:
        _k.hinge_angles(np.ascontiguousarray(np.asarray(x, dtype=np.float64)), H, out)
    return out


class BendingEnergy(StencilTerm):
    """W = Σ_k k_b,k w_k (θ_k - θ̄_k)², w_k = 3|ē_k|²/(Ā1 + Ā2), over ``hinges`` (h,4) of the global mesh.

    Build from a triangle mesh with :meth:`from_triangles`.  Implements ``ElementTerm`` (12x12 blocks)."""

    def __init__(
        self,
        rest_vertices: np.ndarray,
        hinges: npt.ArrayLike,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        thickness: float | np.ndarray,
        multiplier: float | np.ndarray = 1.0,
        hessian: str = "projected",
    ) -> None:
        """``hessian``: what a PSD Hessian request returns, ``projected`` (the exact Hessian, PSD-projected per
        hinge) or ``gauss_newton`` (2c∇θ∇θᵀ, see ``_bending_kernels``); an exact request is always exact."""
        if hessian not in BENDING_HESSIANS:
            raise ValueError(f"unknown bending hessian {hessian!r}; choose one of {BENDING_HESSIANS}")
        self.hessian = hessian
        X = np.asarray(rest_vertices, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3:
            raise ValueError(f"rest_vertices must be (n, 3), got shape {X.shape}")
        H = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
        if H.size and (H.min() < 0 or H.max() >= X.shape[0]):
            raise ValueError(f"hinges index vertices outside [0, {X.shape[0]})")
        self.hinges = np.ascontiguousarray(H)
        self.num_vertices = X.shape[0]
        self._dofs = vertex_dofs(self.hinges)
        self.set_material(youngs_modulus, poisson_ratio, thickness, multiplier)
        self.set_rest_shape(X)

    @classmethod
    def from_triangles(
        cls,
        rest_vertices: np.ndarray,
        triangles: npt.ArrayLike,
        youngs_modulus: float,
        poisson_ratio: float,
        thickness: float,
        multiplier: float = 1.0,
        hessian: str = "projected",
    ) -> BendingEnergy:
        """Bending on every interior edge of ``triangles`` (see ``idp.mesh.hinges.triangle_hinges``)."""
        return cls(
            rest_vertices, triangle_hinges(triangles), youngs_modulus, poisson_ratio, thickness, multiplier, hessian
        )

    def set_material(
        self,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        thickness: float | np.ndarray,
        multiplier: float | np.ndarray = 1.0,
    ) -> None:
        """(Re)set k_b = Y t³/(24(1-ν²)) × multiplier (scalars or per hinge)."""
        h = self.hinges.shape[0]
        self.kb = np.ascontiguousarray(
            per_item(bending_stiffness(youngs_modulus, poisson_ratio, thickness, multiplier), h, "bending stiffness")
        )
        if hasattr(self, "weights"):
            self._stiffness = np.ascontiguousarray(self.kb * self.weights)

    def set_rest_shape(self, rest_vertices: np.ndarray) -> None:
        """Rest angles θ̄ and weights 3|ē|²/(Ā1+Ā2) from ``rest_vertices`` (n,3); ValueError naming the first
        hinge whose rest faces have zero total area."""
        X = positions(rest_vertices, self.num_vertices)
        H = self.hinges
        e = X[H[:, 1]] - X[H[:, 0]]
        a1 = 0.5 * np.linalg.norm(np.cross(e, X[H[:, 2]] - X[H[:, 0]]), axis=1)
        a2 = 0.5 * np.linalg.norm(np.cross(e, X[H[:, 3]] - X[H[:, 0]]), axis=1)
        area = a1 + a2
        bad = np.flatnonzero(~(area > 0))
        if bad.size:
            k = int(bad[0])
            raise ValueError(f"hinge {k} (vertices {H[k].tolist()}) has degenerate rest faces")
        self.weights = np.ascontiguousarray(3.0 * np.einsum("ij,ij->i", e, e) / area)
        self._stiffness = np.ascontiguousarray(self.kb * self.weights)
        self.rest_angles = dihedral_angles(X, H)

    def set_rest_angles(self, angles: float | np.ndarray) -> None:
        """Replace the rest angles θ̄ (scalar or (h,)), keeping the weights (e.g. a scripted fold)."""
        self.rest_angles = per_item(angles, self.hinges.shape[0], "rest angles").copy()

    def angles(self, x: np.ndarray) -> np.ndarray:
        """(h,) current signed dihedral angles."""
        return dihedral_angles(positions(x, self.num_vertices), self.hinges)

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
        _k.bending_terms(
            x,
            self.hinges[first:last],
            self.rest_angles[first:last],
            self._stiffness[first:last],
            want_grad,
            want_hess,
            project,
            project and self.hessian == "gauss_newton",
            e,
            g,
            h,
        )
