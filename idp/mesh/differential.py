"""Discrete differential operators on triangle meshes for the normal-flow (shell) scenes (paper §7.2).

* ``vertex_normals``: area-weighted vertex normals N_i = Σ_{t∋i} A_t n̂_t = Σ_{t∋i} ½ (x1-x0)×(x2-x0),
  oriented by the face winding (outward for a closed, outward-wound surface); optionally unit.
* ``vertex_areas``: lumped (barycentric) vertex areas Σ_{t∋i} A_t/3.
* ``cotangent_laplacian``: L_ij = ½ (cot α_ij + cot β_ij) for an edge ij, L_ii = -Σ_j L_ij: negative
  semidefinite, L·1 = 0, and L f = 0 at interior vertices of a flat mesh for linear f.
* ``area_laplacian``: the element-area-weighted umbrella Laplacian, w_ij = Σ_{t∋ij} A_t/6 (non-negative, so
  negative semidefinite): exactly the smoothing of the authors' normal flow, so γ is their smoothIntensity.
* ``LaplacianSmoothing``: E = -γ ½ xᵀ L x (each coordinate) as an ``ElementTerm`` over triangles (9x9
  blocks, PSD per triangle without any clamping: see the class); ``weights`` picks cotangent or area.
* ``NormalForce``: the linear term E = -β Σ_i N_i·x_i with N frozen (``update`` once per step);
  ``weighting`` picks N_i = Σ_{t∋i} A_t n̂_t/3 ("area") or N_i = m_i n̂_i ("lumped_unit").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from idp.energies._stencil_term import StencilTerm, positions, vertex_dofs
from idp.energies.term import HessianSink


def _mesh(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"vertices must be (n, 3), got shape {X.shape}")
    if T.ndim != 2 or T.shape[1] != 3:
        raise ValueError(f"triangles must be (m, 3), got shape {T.shape}")
    if T.size and (T.min() < 0 or T.max() >= X.shape[0]):
        raise ValueError(f"triangles index vertices outside [0, {X.shape[0]})")
    return X, T


def face_area_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m,3) A_t n̂_t = ½ (x1-x0)×(x2-x0) per triangle (winding-oriented)."""
    X, T = _mesh(vertices, triangles)
    xe = X[T]
    return 0.5 * np.cross(xe[:, 1] - xe[:, 0], xe[:, 2] - xe[:, 0])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray, unit: bool = False) -> np.ndarray:
    """(n,3) area-weighted vertex normals Σ_{t∋i} A_t n̂_t; with ``unit`` normalised (zero stays zero)."""
    X, T = _mesh(vertices, triangles)
    fn = face_area_normals(X, T)
    N = np.zeros_like(X)
    for c in range(3):
        np.add.at(N, T[:, c], fn)
    if unit:
        nrm = np.linalg.norm(N, axis=1, keepdims=True)
        N = np.divide(N, nrm, out=np.zeros_like(N), where=nrm > 0)
    return N


def vertex_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n,) lumped vertex areas Σ_{t∋i} A_t / 3."""
    X, T = _mesh(vertices, triangles)
    a = np.linalg.norm(face_area_normals(X, T), axis=1) / 3.0
    return np.bincount(T.ravel(), weights=np.repeat(a, 3), minlength=X.shape[0])


def cotangent_weights(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m,3) ½ cot of the angle at corner c of each triangle: the weight of edge (c+1, c+2) in that
    triangle.  A zero-area triangle gets weights 0 (its cotangents do not exist)."""
    X, T = _mesh(vertices, triangles)
    xe = X[T]
    w = np.zeros(T.shape)
    for c in range(3):
        u = xe[:, (c + 1) % 3] - xe[:, c]
        v = xe[:, (c + 2) % 3] - xe[:, c]
        cr = np.linalg.norm(np.cross(u, v), axis=1)
        dot = np.einsum("ij,ij->i", u, v)
        w[:, c] = 0.5 * np.divide(dot, cr, out=np.zeros_like(dot), where=cr > 0)
    return w


def area_weights(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m,3) A_t/6 at every corner c of each triangle: the weight of edge (c+1, c+2) in that triangle, so an
    interior edge gets (A_1+A_2)/6.  Non-negative, hence PSD smoothing blocks.

    This is the paper's "element volume weighted Laplacian" as the authors' flow builds it (ipc-sim/IDP,
    FEMShell's flow potential: each triangle adds (A_t/6)(x_j + x_k − 2x_i) to (Lx)_i, with A_t from the
    initial shape and kept), so with idp's h = 1 the authors' step h·(−½xᵀLx) at their h = smoothIntensity s
    is exactly γ = s."""
    X, T = _mesh(vertices, triangles)
    a = np.linalg.norm(face_area_normals(X, T), axis=1) / 6.0
    return np.repeat(a[:, None], 3, axis=1)


_EDGE_WEIGHTS = {"cotangent": cotangent_weights, "area": area_weights}


def _laplacian_from_weights(T: np.ndarray, w: np.ndarray, n: int) -> sp.csr_matrix:
    """L with L_ij = Σ weights of edge ij, L_ii = -Σ_j L_ij (n x n CSR)."""
    i = np.concatenate([T[:, 1], T[:, 2], T[:, 0]])
    j = np.concatenate([T[:, 2], T[:, 0], T[:, 1]])
    ww = np.concatenate([w[:, 0], w[:, 1], w[:, 2]])
    off = sp.coo_matrix((ww, (i, j)), shape=(n, n))
    off = off + off.T
    diag = np.asarray(off.sum(axis=1)).ravel()
    return (off - sp.diags(diag)).tocsr()


def cotangent_laplacian(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """(n,n) cotangent Laplacian L (negative semidefinite when every edge weight is ≥ 0, rows sum to 0)."""
    X, T = _mesh(vertices, triangles)
    return _laplacian_from_weights(T, cotangent_weights(X, T), X.shape[0])


def area_laplacian(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """(n,n) area-weighted graph Laplacian, L_ij = Σ_{t∋ij} A_t/6 (negative semidefinite, rows sum to 0)."""
    X, T = _mesh(vertices, triangles)
    return _laplacian_from_weights(T, area_weights(X, T), X.shape[0])


class LaplacianSmoothing(StencilTerm):
    """E(x) = γ/2 Σ_t Σ_c w_tc |x_{c+1} - x_{c+2}|² = -γ ½ xᵀ L_w x (per coordinate), as 9x9 blocks γ K_t ⊗ I₃.

    The edge weights w_tc = ½ cot of the opposite angle are taken from ``vertices`` at construction (or
    ``set_weights``) and fixed, so the Hessian is the constant -γ L_w ⊗ I₃.  Each K_t (the triangle's
    3x3 cotangent matrix) is the P1 finite-element stiffness matrix A_t ∇φᵀ∇φ of that triangle, a Gram
    matrix, hence PSD *even when an angle is obtuse* (a negative cot weight): no clamping is needed for
    PSD blocks, and by default none is done (L_w = L exactly).  ``clamp_negative=True`` sets negative
    weights to 0 (L_w then has non-negative off-diagonals, an M-matrix, at the price of no longer being the
    cotangent Laplacian on obtuse meshes); blocks stay PSD either way.  ``project`` replaces K_t by its PSD
    part (3x3 eigen-decomposition), which only removes rounding-level negative eigenvalues.

    ``weights="area"`` uses w_tc = A_t/6 instead (``area_weights``): the umbrella-type graph Laplacian of
    the authors' normal flow, whose weights come from the initial triangle areas and are not updated.
    They are non-negative, so ``clamp_negative`` changes nothing for them."""

    def __init__(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        gamma: float,
        clamp_negative: bool = False,
        weights: str = "cotangent",
    ) -> None:
        X, T = _mesh(vertices, triangles)
        if not (np.isfinite(gamma) and gamma >= 0):
            raise ValueError(f"gamma must be finite and >= 0, got {gamma!r}")
        if weights not in _EDGE_WEIGHTS:
            raise ValueError(f"weights must be one of {sorted(_EDGE_WEIGHTS)}, got {weights!r}")
        self.weights = weights
        self.triangles = np.ascontiguousarray(T)
        self.num_vertices = X.shape[0]
        self.gamma = float(gamma)
        self.clamp_negative = bool(clamp_negative)
        self._dofs = vertex_dofs(self.triangles)
        self.set_weights(X)

    def set_weights(self, vertices: np.ndarray) -> None:
        """Recompute the edge weights (``weights`` kind, clamped at 0 if ``clamp_negative``) from ``vertices`` (n,3)."""
        w = _EDGE_WEIGHTS[self.weights](positions(vertices, self.num_vertices), self.triangles)
        if self.clamp_negative:
            w = np.maximum(w, 0.0)
        self.edge_weights = w
        # K_t = Σ_c w_c (δ_{c+1} - δ_{c+2})(δ_{c+1} - δ_{c+2})ᵀ  (3x3 per triangle)
        m = self.triangles.shape[0]
        K = np.zeros((m, 3, 3))
        for c in range(3):
            p, q = (c + 1) % 3, (c + 2) % 3
            K[:, p, p] += w[:, c]
            K[:, q, q] += w[:, c]
            K[:, p, q] -= w[:, c]
            K[:, q, p] -= w[:, c]
        self._K = K
        lam, V = np.linalg.eigh(K) if m else (np.zeros((0, 3)), np.zeros((0, 3, 3)))
        self._K_psd = np.einsum("mij,mj,mkj->mik", V, np.maximum(lam, 0.0), V)
        # -L_w (n x n): value and gradient of the whole term are one sparse product, and the 9x9 blocks, constant
        # until the weights change, are built once per (γ, project) and handed out from then on
        self._neg_laplacian = -_laplacian_from_weights(self.triangles, w, self.num_vertices)
        self._block_cache: tuple[float, bool, np.ndarray] | None = None

    def laplacian(self) -> sp.csr_matrix:
        """(n,n) L_w with the weights in use (clamped if ``clamp_negative``); the Hessian is -γ L_w ⊗ I₃."""
        return _laplacian_from_weights(self.triangles, self.edge_weights, self.num_vertices)

    def _quadratic(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """(E, ∇E) = (½ xᵀ A x, A x) per coordinate with A = -γ L_w: the sum over triangles as one product."""
        X = positions(x, self.num_vertices)
        AX = self.gamma * (self._neg_laplacian @ X)
        return 0.5 * float(np.sum(X * AX)), AX.reshape(-1)

    def value(self, x: np.ndarray) -> float:
        """Total energy -γ ½ xᵀ L_w x."""
        return self._quadratic(x)[0]

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·3,) gradient -γ L_w x."""
        return self._quadratic(x)[1]

    def _blocks(self, project: bool) -> np.ndarray:
        """(m, 9, 9) γ K_t ⊗ I₃ (K_t's PSD part if ``project``), built once for the current weights, γ and flag."""
        cache = self._block_cache
        if cache is None or cache[0] != self.gamma or cache[1] != project:
            m = self.num_stencils
            blocks = np.zeros((m, 9, 9))
            e, g = np.zeros(m), np.zeros((m, 9))
            if m:
                self._kernel(np.zeros((self.num_vertices, 3)), 0, m, False, True, project, e, g, blocks)
            cache = self._block_cache = (self.gamma, project, blocks)
        return cache[2]

    def value_gradient_hessian_groups(
        self,
        x: np.ndarray,
        sink: HessianSink,
        project: bool = True,
        group: int = 4096,
        skip: np.ndarray | None = None,
    ) -> tuple[float, np.ndarray]:
        """As ``StencilTerm``'s, with the energy and gradient from the sparse product and the Hessian blocks from
        the cache (the sink must only read them). With ``skip`` the stencil-wise evaluation of the base class."""
        if skip is not None:
            return super().value_gradient_hessian_groups(x, sink, project, group, skip)
        energy, grad = self._quadratic(x)
        blocks = self._blocks(bool(project))
        for a in range(0, self.num_stencils, group):
            sink(a, blocks[a : a + group])
        return energy, grad

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
        K = self.gamma * self._K[first:last]
        xe = x[self.triangles[first:last]]  # (g,3 vertices,3 coords)
        Kx = np.matmul(K, xe)
        e[:] = 0.5 * (xe * Kx).sum(axis=(1, 2))
        if want_grad:
            g[:] = Kx.reshape(-1, 9)
        if want_hess:
            # K_t ⊗ I₃ (vertex-major DOFs): K_t on each coordinate's diagonal, zeros between coordinates
            # (strided copies: einsum's outer product with I₃ took 5× as long)
            Kh = self.gamma * self._K_psd[first:last] if project else K
            blocks = np.zeros((Kh.shape[0], 3, 3, 3, 3))
            for c in range(3):
                blocks[:, :, c, :, c] = Kh
            h[:] = blocks.reshape(-1, 9, 9)


class NormalForce:
    """Linear term E(x) = -β Σ_i N_i·x_i (gradient -β N, zero Hessian) pushing vertices along frozen normals N.

    ``update(x)`` sets N from the current shape; call it once per step (the normal flow recomputes the
    force from the current shape each step).  ``weighting="area"`` (default): N_i = Σ_{t∋i} (A_t/3) n̂_t,
    the area-weighted normal with the lumped (area/3) weighting.  ``weighting="lumped_unit"``: N_i = m_i n̂_i
    with m_i = Σ_{t∋i} A_t/3 the lumped area of the shape given to ``update`` and n̂_i the unit area-weighted
    vertex normal, so |N_i| = m_i wherever n̂_i exists.  (The authors' force is m_i n̂_i with the masses of M,
    which the normal flow sets with ``set_normals``.)
    ``set_normals`` sets N directly.  No stencils: ``element_dofs`` is empty and no Hessian block is ever
    handed to the sink."""

    WEIGHTINGS = ("area", "lumped_unit")

    def __init__(self, triangles: np.ndarray, num_vertices: int, beta: float, weighting: str = "area") -> None:
        T = np.asarray(triangles, dtype=np.int64)
        if T.ndim != 2 or T.shape[1] != 3:
            raise ValueError(f"triangles must be (m, 3), got shape {T.shape}")
        if weighting not in self.WEIGHTINGS:
            raise ValueError(f"weighting must be one of {list(self.WEIGHTINGS)}, got {weighting!r}")
        self.weighting = weighting
        self.triangles = np.ascontiguousarray(T)
        self.num_vertices = int(num_vertices)
        self.beta = float(beta)
        self.normals = np.zeros((self.num_vertices, 3))

    def update(self, x: np.ndarray) -> None:
        """N from the shape ``x``: vertex_normals(x)/3 ("area") or vertex_areas(x)·unit vertex normal
        ("lumped_unit")."""
        X = positions(x, self.num_vertices)
        if self.weighting == "area":
            self.normals = vertex_normals(X, self.triangles) / 3.0
        else:
            unit = vertex_normals(X, self.triangles, unit=True)
            self.normals = vertex_areas(X, self.triangles)[:, None] * unit

    def set_normals(self, normals: np.ndarray) -> None:
        """Use the given (n,3) N."""
        N = np.array(normals, dtype=np.float64)
        if N.shape != (self.num_vertices, 3):
            raise ValueError(f"normals must be ({self.num_vertices}, 3), got {N.shape}")
        self.normals = N

    def element_dofs(self) -> np.ndarray:
        """No stencils: (0, 3)."""
        return np.zeros((0, 3), dtype=np.int64)

    def value(self, x: np.ndarray) -> float:
        """-β Σ_i N_i·x_i."""
        return float(-self.beta * np.sum(self.normals * positions(x, self.num_vertices)))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """-β N, flat (n·3,)."""
        return -self.beta * self.normals.reshape(-1)

    def value_gradient_hessian_groups(
        self, x: np.ndarray, sink: HessianSink, project: bool = True, group: int = 4096
    ) -> tuple[float, np.ndarray]:
        """(value, gradient); the Hessian is zero, so ``sink`` is never called."""
        return self.value(x), self.gradient(x)


__all__ = [
    "LaplacianSmoothing",
    "NormalForce",
    "area_laplacian",
    "area_weights",
    "cotangent_laplacian",
    "cotangent_weights",
    "face_area_normals",
    "vertex_areas",
    "vertex_normals",
]
