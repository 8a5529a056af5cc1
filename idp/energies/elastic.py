"""Distortion energies E(x) = sum_t v_t Psi(F_t) on tetrahedra (3D) and triangles (2D).

Models (paper §4.4): the barriers neo-Hookean and symmetric Dirichlet, both -> +inf as
det F -> 0+, so a line search with the inversion filter (``idp.energies.inversion_filter``)
keeps every element positively oriented; and the non-barrier ARAP (mu ||F - R||^2) and
St. Venant-Kirchhoff (mu ||E||^2 + lambda/2 tr(E)^2), finite for inverted elements too, which
therefore do not guard inversion.  Material parameters are per element so several materials
coexist.  Element Hessians are made PSD per element through the analytic singular-value
eigensystem (see ``_elastic_kernels``), as projected Newton needs.

Rest frames (paper §4.5): F_t = Ds_t Dm_t^{-1} with the effective rest frame Dm_t = T_t Dm_base_t.
The base frames start as the input rest shape; ``bake`` replaces them by the current shape and
plasticity deforms them; the rest transform T (``set_rest_scale`` / ``set_rest_transform``, the
scripted growth and shape changes) is applied on top and reset by ``bake``.
"""

from __future__ import annotations

import numpy as np

from idp.energies import _elastic_kernels as _k
from idp.energies.inversion_filter import max_inversion_free_step

MODELS = {
    "neo_hookean": _k.NEO_HOOKEAN,
    "symmetric_dirichlet": _k.SYMMETRIC_DIRICHLET,
    "arap": _k.ARAP,
    "stvk": _k.STVK,
}

#: Models that are barriers (+inf for det F <= 0) and so need the inversion filter in the line search.
BARRIER_MODELS = frozenset({"neo_hookean", "symmetric_dirichlet"})


def rest_frames(rest_vertices: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Dm_inv (m,d,d), rest_volumes (m,)) with Dm = [x1-x0, .., xd-x0] of the rest shape.

    Raises ValueError naming the first element whose rest volume/area is not positive
    (degenerate or wrongly oriented), since Dm^{-1} and the barrier need it.
    """
    X = np.asarray(rest_vertices, dtype=np.float64)
    T = np.asarray(elements, dtype=np.int64)
    if X.ndim != 2 or X.shape[1] not in (2, 3):
        raise ValueError(f"rest_vertices must be (n, 2) or (n, 3), got shape {X.shape}")
    d = X.shape[1]
    if T.ndim != 2 or T.shape[1] != d + 1:
        raise ValueError(f"elements must be (m, {d + 1}) for {d}D vertices, got shape {T.shape}")
    if T.size and (T.min() < 0 or T.max() >= X.shape[0]):
        raise ValueError(f"elements index vertices outside [0, {X.shape[0]})")
    Dm = _rest_matrices(X, T)
    det = np.linalg.det(Dm) if len(T) else np.zeros(0)
    bad = np.flatnonzero(~(det > 0))
    if bad.size:
        t = int(bad[0])
        raise ValueError(
            f"element {t} (vertices {T[t].tolist()}) has non-positive rest "
            f"{'volume' if d == 3 else 'area'} {det[t] / (6.0 if d == 3 else 2.0):.3e}"
        )
    fact = 6.0 if d == 3 else 2.0
    return np.linalg.inv(Dm), det / fact


def _rest_matrices(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Dm (m,d,d) with columns x_a - x_0."""
    xe = X[T]
    return np.ascontiguousarray(np.transpose(xe[:, 1:, :] - xe[:, :1, :], (0, 2, 1)))


def lame_parameters(
    youngs_modulus: float | np.ndarray, poisson_ratio: float | np.ndarray
) -> tuple[float | np.ndarray, float | np.ndarray]:
    """(mu, lambda) from Young's modulus E > 0 and Poisson ratio -1 < nu < 0.5 (scalars or arrays)."""
    E = np.asarray(youngs_modulus, dtype=np.float64)
    nu = np.asarray(poisson_ratio, dtype=np.float64)
    if not np.all(np.isfinite(E) & (E > 0)):
        raise ValueError(f"youngs_modulus must be finite and > 0, got {youngs_modulus!r}")
    if not np.all((nu > -1.0) & (nu < 0.5)):
        raise ValueError(f"poisson_ratio must lie in (-1, 0.5), got {poisson_ratio!r}")
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    if mu.ndim == 0:
        return float(mu), float(lam)
    return mu, lam


def _per_element(value: float | np.ndarray, m: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(m, float(arr))
    if arr.shape != (m,):
        raise ValueError(f"{name} must be a scalar or shape ({m},), got {arr.shape}")
    return np.ascontiguousarray(arr)


class ElasticEnergy:
    """E(x) = sum_t v_t Psi(F_t) over a set of elements of the global mesh.

    ``elements`` (m, d+1) index the global vertex array; ``rest_vertices`` is the global rest
    array (n, d).  ``x`` arguments are (n, d) (or flat (n*d,)) float64.  Gradients are flat
    (n*d,) interleaved [x0, y0, (z0), x1, ...]; element Hessians are (m, k, k), k = (d+1) d, in
    vertex-major local order matching ``element_dofs()``.  For the barrier models (NH, SD), elements
    with det F <= 0 have value +inf and NaN gradient / Hessian (only feasible states are meaningful);
    ARAP and StVK are finite there.

    Material: NH and StVK use (mu, lambda) from (E, nu); SD uses ``weight`` (default mu/4); ARAP uses
    mu, or ``weight`` when given.  ``weight`` is ignored by NH and StVK.
    """

    def __init__(
        self,
        model: str,
        rest_vertices: np.ndarray,
        elements: np.ndarray,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        weight: float | np.ndarray | None = None,
    ) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown elastic model {model!r}; expected one of {sorted(MODELS)}")
        self.model = model
        self._model_id = MODELS[model]
        X = np.asarray(rest_vertices, dtype=np.float64)
        self.elements = np.ascontiguousarray(np.asarray(elements, dtype=np.int64))
        self.Dm_inv, self.volumes = rest_frames(X, self.elements)
        self.Dm_inv = np.ascontiguousarray(self.Dm_inv)
        self._Dm_base = _rest_matrices(X, self.elements)
        self._transform: np.ndarray | None = None  # None = identity; else (d,d) or (m,d,d)
        self.num_vertices = X.shape[0]
        self.dim = X.shape[1]
        m = self.elements.shape[0]
        self.set_material(youngs_modulus, poisson_ratio, weight)
        self._dofs = (self.elements[:, :, None] * self.dim + np.arange(self.dim)[None, None, :]).reshape(
            m, (self.dim + 1) * self.dim
        )

    def set_material(
        self,
        youngs_modulus: float | np.ndarray,
        poisson_ratio: float | np.ndarray,
        weight: float | np.ndarray | None = None,
    ) -> None:
        """(Re)set the material, scalars or per element (m,): stiffness per stage (§7.5) without rebuilding."""
        m = self.elements.shape[0]
        mu, lam = lame_parameters(
            _per_element(youngs_modulus, m, "youngs_modulus"), _per_element(poisson_ratio, m, "poisson_ratio")
        )
        self.mu = np.asarray(mu, dtype=np.float64).reshape(m)
        self.lam = np.asarray(lam, dtype=np.float64).reshape(m)
        if self._model_id in (_k.NEO_HOOKEAN, _k.STVK):
            self._pa, self._pb = self.mu, self.lam
            return
        default = self.mu / 4.0 if self._model_id == _k.SYMMETRIC_DIRICHLET else self.mu
        w = default if weight is None else _per_element(weight, m, "weight")
        if not np.all(np.isfinite(w) & (w > 0)):
            raise ValueError(f"{self.model} weight must be finite and > 0")
        self.weight = np.ascontiguousarray(w)
        self._pa, self._pb = self.weight, np.zeros(m)

    #: Fraction of an element's current volume the inversion filter lets it shrink to along one step.
    inversion_eta: float = 0.1

    #: Exponent p of the p-norm extension E_p = r(p) Σ v Ψ̂^p (paper eq. 9); 1 is the plain energy
    #: (:class:`idp.energies.pnorm.PNormEnergy` sets it).
    power: float = 1.0

    @property
    def guards_inversion(self) -> bool:
        """True for barrier energies (NH, SD: → +inf as det F → 0⁺): the line search must keep det F > 0.

        False for ARAP and StVK, which are finite for inverted elements."""
        return self.model in BARRIER_MODELS

    def max_step(self, x: np.ndarray, direction: np.ndarray) -> float:
        """Largest α ≤ 1 keeping every element's volume above ``inversion_eta`` × its current value along
        x + α·direction (Smith & Schaefer's filter); 1 for energies that do not guard inversion."""
        if not self.guards_inversion:
            return 1.0
        return max_inversion_free_step(self._x(x), direction, self.elements, self.inversion_eta)

    # ------------------------------------------------------------------ rest shape
    @property
    def rest_frames_inverse(self) -> np.ndarray:
        """(m,d,d) inverses of the effective rest frames, Dm^{-1} = (T Dm_base)^{-1} (same array as ``Dm_inv``)."""
        return self.Dm_inv

    @property
    def base_rest_frames(self) -> np.ndarray:
        """(m,d,d) base rest frames Dm_base (read-only view): the input rest shape, or the baked / plastic one."""
        view = self._Dm_base.view()
        view.flags.writeable = False
        return view

    @property
    def rest_transform(self) -> np.ndarray:
        """The rest transform T applied on top of the base frames: (d,d) shared or (m,d,d) per element."""
        if self._transform is None:
            return np.eye(self.dim)
        return self._transform.copy()

    def _set_transform(self, T: np.ndarray) -> None:
        """Make ``T`` the rest transform; Dm_inv is recomputed only when it changes (every mutator of the base frames
        updates Dm_inv itself, so an unchanged T leaves it right: a growth script holds its last scale for the
        rest of a run, and at bunnyx30_13K each recomputation costs ≈ 0.06 s)."""
        if self._transform is not None and self._transform.shape == T.shape and np.array_equal(self._transform, T):
            return
        self._transform = T
        self._update_rest_frames()

    def _update_rest_frames(self) -> None:
        """Dm_inv = inv(T Dm_base) (T = identity when unset)."""
        Dm = self._Dm_base if self._transform is None else self._transform @ self._Dm_base
        self.Dm_inv = np.ascontiguousarray(np.linalg.inv(Dm)) if len(Dm) else np.zeros_like(Dm)

    def set_rest_scale(self, scale: float | np.ndarray) -> None:
        """Rest shape = base rest shape scaled by ``scale`` (uniform, or per-axis (d,)).

        Dm_inv = inv(diag(scale) Dm_base), i.e. ``set_rest_transform(diag(scale))``; the volume weights
        v_t keep their values (as the reference implementation does during growth)."""
        s = np.asarray(scale, dtype=np.float64)
        if s.ndim == 0:
            s = np.full(self.dim, float(s))
        if s.shape != (self.dim,) or not np.all(np.isfinite(s) & (s > 0)):
            raise ValueError(f"rest scale must be > 0, scalar or shape ({self.dim},), got {scale!r}")
        self._set_transform(np.diag(s))

    def set_rest_transform(self, transform: np.ndarray) -> None:
        """Rest frames Dm = T Dm_base with T (d,d) shared or (m,d,d) per element (anisotropic / per-region scale).

        Replaces any previous scale or transform (it does not compose with it); T must be finite with
        det T > 0 (orientation-preserving).  The volume weights keep their values, as in ``set_rest_scale``."""
        T = np.array(transform, dtype=np.float64)
        d, m = self.dim, self.elements.shape[0]
        if T.shape not in ((d, d), (m, d, d)):
            raise ValueError(f"rest transform must have shape ({d}, {d}) or ({m}, {d}, {d}), got {T.shape}")
        if not np.all(np.isfinite(T)):
            raise ValueError("rest transform must be finite")
        det = np.linalg.det(T)
        bad = np.flatnonzero(~(np.atleast_1d(det) > 0))
        if bad.size:
            where = "" if T.ndim == 2 else f" of element {int(bad[0])}"
            raise ValueError(f"rest transform{where} must have det > 0, got {np.atleast_1d(det)[bad[0]]:.3e}")
        self._set_transform(T)

    def bake(self, x: np.ndarray) -> None:
        """Make the shape ``x`` the rest shape (§4.5): base frames = current Ds, volume weights = current
        volumes, rest transform reset to identity.  Raises ValueError naming the first element of ``x`` with
        non-positive volume (a rest frame must be positively oriented)."""
        xc = self._x(x)
        if self.elements.shape[0]:
            Dm_inv, vol = rest_frames(xc, self.elements)
        else:
            Dm_inv, vol = np.zeros((0, self.dim, self.dim)), np.zeros(0)
        self._Dm_base = _rest_matrices(xc, self.elements)
        self.volumes = np.ascontiguousarray(vol)
        self._transform = None
        self.Dm_inv = np.ascontiguousarray(Dm_inv)

    def set_base_rest_frames(self, base: np.ndarray, volumes: np.ndarray) -> None:
        """Restore base rest frames and volume weights saved from :meth:`base_rest_frames` / ``volumes`` (a
        checkpoint of a plastic or baked state); the current rest transform stays on top."""
        base = np.array(base, dtype=np.float64)
        vol = np.array(volumes, dtype=np.float64)
        m, d = self.elements.shape[0], self.dim
        if base.shape != (m, d, d) or vol.shape != (m,):
            raise ValueError(
                f"saved rest frames have shapes {base.shape}, {vol.shape}; this energy needs ({m}, {d}, {d})"
            )
        self._Dm_base = np.ascontiguousarray(base)
        self.volumes = np.ascontiguousarray(vol)
        self._update_rest_frames()

    def deform_rest_frames(self, G: np.ndarray, which: np.ndarray | None = None) -> None:
        """Effective rest frames Dm ← G Dm per element, e.g. a plastic flow F_p (G (k,d,d) with det G > 0, for
        the elements ``which`` (k,) indices, or all m elements when None; the others are left bit-for-bit).

        Stored in the base frames as Dm_base ← T⁻¹ G T Dm_base so that a rest transform T set before stays
        applied on top (and later transforms act on the deformed base).  The volume weights keep their
        values (plastic flow is isochoric, det G = 1)."""
        G = np.asarray(G, dtype=np.float64)
        m, d = self.elements.shape[0], self.dim
        idx = np.arange(m) if which is None else np.asarray(which, dtype=np.int64).reshape(-1)
        if G.shape != (idx.size, d, d):
            raise ValueError(f"rest-frame update must have shape ({idx.size}, {d}, {d}), got {G.shape}")
        if idx.size == 0:
            return
        base = self._Dm_base[idx]
        if self._transform is None:
            new = G @ base
        else:
            T = self._transform if self._transform.ndim == 2 else self._transform[idx]
            T = np.broadcast_to(T, (idx.size, d, d))
            new = np.linalg.solve(T, G @ (T @ base))
        self._Dm_base[idx] = new
        Dm = new if self._transform is None else T @ new
        self.Dm_inv[idx] = np.linalg.inv(Dm)

    def deformation_gradients(self, x: np.ndarray) -> np.ndarray:
        """(m,d,d) F = Ds Dm^{-1} per element at ``x``."""
        return _rest_matrices(self._x(x), self.elements) @ self.Dm_inv

    # ------------------------------------------------------------------ evaluation
    def _x(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 1:
            x = x.reshape(-1, self.dim)
        if x.shape != (self.num_vertices, self.dim):
            raise ValueError(f"x must be ({self.num_vertices}, {self.dim}), got {x.shape}")
        return np.ascontiguousarray(x)

    def _run(self, x: np.ndarray, grad: bool, hess: bool, project: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m = self.elements.shape[0]
        k = (self.dim + 1) * self.dim
        e = np.empty(m)
        g = np.empty((m, k)) if grad else np.empty((0, k))
        h = np.empty((m, k, k)) if hess else np.empty((0, k, k))
        if m:
            _k.element_terms(
                self._x(x),
                self.elements,
                self.Dm_inv,
                self.volumes,
                self._model_id,
                self._pa,
                self._pb,
                grad,
                hess,
                bool(project),
                self.power,
                e,
                g,
                h,
            )
        return e, g, h

    def _scatter(self, g: np.ndarray) -> np.ndarray:
        n = self.num_vertices * self.dim
        if g.size == 0:
            return np.zeros(n)
        return np.bincount(self._dofs.ravel(), weights=g.ravel(), minlength=n)

    def value(self, x: np.ndarray) -> float:
        """Total energy; +inf if a barrier model (NH, SD) has an element with det F <= 0."""
        e, _, _ = self._run(x, False, False, False)
        return float(e.sum())

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n*d,) gradient."""
        _, g, _ = self._run(x, True, False, False)
        return self._scatter(g)

    def element_hessians(self, x: np.ndarray, project: bool = True) -> np.ndarray:
        """(m, k, k) element Hessians; PSD-projected per element if ``project`` else exact."""
        _, _, h = self._run(x, False, True, project)
        return h

    def element_dofs(self) -> np.ndarray:
        """(m, k) global DOF indices (vertex*d + coord) of each element block."""
        return self._dofs

    def value_gradient_hessian(self, x: np.ndarray, project: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
        """(energy, flat gradient, element Hessians (m,k,k)) from one fused kernel pass."""
        e, g, h = self._run(x, True, True, project)
        return float(e.sum()), self._scatter(g), h

    def value_gradient_hessian_groups(
        self, x: np.ndarray, sink, project: bool = True, group: int = 4096
    ) -> tuple[float, np.ndarray]:
        """(energy, flat gradient); the element Hessians are handed to ``sink(first, blocks)`` group by
        group (blocks (g, k, k) of elements first … first+g−1, overwritten after the call), so only one
        group is ever held: at 74K tets that is 4.7 MB instead of 86 MB for all of them."""
        m = self.elements.shape[0]
        k = (self.dim + 1) * self.dim
        xc = self._x(x)
        e = np.empty(m)
        g = np.empty((m, k))
        buf = np.empty((min(group, max(m, 1)), k, k))
        for a in range(0, m, group):
            b = min(m, a + group)
            h = buf[: b - a]
            _k.element_terms(
                xc,
                self.elements[a:b],
                self.Dm_inv[a:b],
                self.volumes[a:b],
                self._model_id,
                self._pa[a:b],
                self._pb[a:b],
                True,
                True,
                bool(project),
                self.power,
                e[a:b],
                g[a:b],
                h,
            )
            sink(a, h)
        return float(e.sum()), self._scatter(g)

    def gradient_hessian_into(
        self, x: np.ndarray, scatter: tuple, data: np.ndarray, weight: float, project: bool = True
    ) -> np.ndarray:
        """Flat gradient; the element Hessians × ``weight`` are added straight into the matrix values ``data``
        through ``scatter`` (:meth:`idp.solver.assembly.FixedPatternAssembler.fused_scatter`), never held. The
        same gradient and values, bit for bit, as :meth:`value_gradient_hessian_groups` followed by the
        assembler's scatter."""
        owner, ptr, part_elements, base, stride = scatter
        g = np.zeros(self.num_vertices * self.dim)
        if self.elements.shape[0]:
            _k.element_terms_scatter(
                self._x(x),
                self.elements,
                self.Dm_inv,
                self.volumes,
                self._model_id,
                self._pa,
                self._pb,
                bool(project),
                self.power,
                owner,
                ptr,
                part_elements,
                base,
                stride,
                float(weight),
                data,
                g,
            )
        return g

    def min_jacobian(self, x: np.ndarray) -> float:
        """Smallest det F over the elements (diagnostics; +inf with no elements)."""
        if self.elements.shape[0] == 0:
            return float("inf")
        return float(_k.element_jacobians(self._x(x), self.elements, self.Dm_inv).min())
