"""Shared plumbing of the shell terms (membrane, bending, Laplacian smoothing): DOF stencils, input
checking, gradient scatter and the grouped Hessian streaming of the ``ElementTerm`` protocol."""

from __future__ import annotations

import numpy as np

from idp.energies.term import HessianSink


def vertex_dofs(stencils: np.ndarray, dim: int = 3) -> np.ndarray:
    """(m, s·dim) global DOFs (vertex·dim + coordinate, vertex-major) of (m, s) vertex stencils."""
    st = np.asarray(stencils, dtype=np.int64)
    m, s = st.shape
    return np.ascontiguousarray((st[:, :, None] * dim + np.arange(dim)[None, None, :]).reshape(m, s * dim))


def per_item(value: float | np.ndarray, m: int, name: str) -> np.ndarray:
    """A scalar broadcast to (m,), or an (m,) array, as contiguous float64."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(m, float(arr))
    if arr.shape != (m,):
        raise ValueError(f"{name} must be a scalar or shape ({m},), got {arr.shape}")
    return np.ascontiguousarray(arr)


def positions(x: np.ndarray, num_vertices: int) -> np.ndarray:
    """``x`` as a contiguous (n, 3) float64 array (flat (n·3,) accepted)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:
        x = x.reshape(-1, 3)
    if x.shape != (num_vertices, 3):
        raise ValueError(f"x must be ({num_vertices}, 3), got {x.shape}")
    return np.ascontiguousarray(x)


def scatter_gradient(dofs: np.ndarray, g: np.ndarray, num_dofs: int) -> np.ndarray:
    """Flat (num_dofs,) sum of per-stencil gradients g (m, k) at their DOFs."""
    if g.size == 0:
        return np.zeros(num_dofs)
    return np.bincount(dofs.ravel(), weights=g.ravel(), minlength=num_dofs)


class StencilTerm:
    """Base of the kernel-backed shell terms: subclasses set ``num_vertices``, ``_dofs`` and implement
    ``_kernel(x, first, last, want_grad, want_hess, project, e, g, h)`` over stencils [first, last)."""

    num_vertices: int
    _dofs: np.ndarray

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
        raise NotImplementedError

    @property
    def num_stencils(self) -> int:
        return int(self._dofs.shape[0])

    @property
    def stencil_size(self) -> int:
        return int(self._dofs.shape[1])

    def element_dofs(self) -> np.ndarray:
        """(m, k) global DOF indices (vertex·3 + coordinate) of each stencil, vertex-major."""
        return self._dofs

    def _run(self, x: np.ndarray, grad: bool, hess: bool, project: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m, k = self.num_stencils, self.stencil_size
        e = np.zeros(m)
        g = np.zeros((m, k)) if grad else np.zeros((0, k))
        h = np.zeros((m, k, k)) if hess else np.zeros((0, k, k))
        if m:
            self._kernel(positions(x, self.num_vertices), 0, m, grad, hess, bool(project), e, g, h)
        return e, g, h

    def element_energies(self, x: np.ndarray) -> np.ndarray:
        """(m,) energy of each stencil."""
        return self._run(x, False, False, False)[0]

    def value(self, x: np.ndarray) -> float:
        """Total energy."""
        return float(self.element_energies(x).sum())

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·3,) gradient."""
        _, g, _ = self._run(x, True, False, False)
        return scatter_gradient(self._dofs, g, 3 * self.num_vertices)

    def element_hessians(self, x: np.ndarray, project: bool = True) -> np.ndarray:
        """(m, k, k) stencil Hessians, PSD-projected per stencil if ``project`` else exact."""
        return self._run(x, False, True, project)[2]

    def value_gradient_hessian_groups(
        self,
        x: np.ndarray,
        sink: HessianSink,
        project: bool = True,
        group: int = 4096,
        skip: np.ndarray | None = None,
    ) -> tuple[float, np.ndarray]:
        """(energy, flat gradient); stencil Hessians handed to ``sink(first, blocks)`` group by group (the
        buffer is reused, so the sink must consume the blocks before returning). ``skip``: (m,) bool, stencils
        left out (no energy, gradient or Hessian: the caller knows they act on held DOFs only); the others are
        computed in runs of consecutive stencils."""
        m, k = self.num_stencils, self.stencil_size
        xc = positions(x, self.num_vertices)
        e = np.zeros(m)
        g = np.zeros((m, k))
        buf = np.zeros((min(group, max(m, 1)), k, k))
        for first, last in _runs(m, skip):
            for a in range(first, last, group):
                b = min(last, a + group)
                h = buf[: b - a]
                self._kernel(xc, a, b, True, True, bool(project), e[a:b], g[a:b], h)
                sink(a, h)
        return float(e.sum()), scatter_gradient(self._dofs, g, 3 * self.num_vertices)


#: Skipped stencils between two runs of kept ones are evaluated anyway (and their blocks scattered) when there are
#: fewer than this many: each kernel call costs a parallel launch, and the mannequin's held head leaves its hinges
#: in ~50 runs interleaved with short gaps (measured: a call per run was no faster than evaluating everything).
MIN_SKIPPED_RUN = 256


def _runs(m: int, skip: np.ndarray | None, min_gap: int = MIN_SKIPPED_RUN) -> list[tuple[int, int]]:
    """[first, last) ranges of the stencils to evaluate: those not skipped, joined across gaps shorter than
    ``min_gap`` skipped stencils."""
    if skip is None:
        return [(0, m)] if m else []
    keep = np.concatenate(([0], (~np.asarray(skip, dtype=bool)).astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(keep))
    runs: list[tuple[int, int]] = []
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        if runs and a - runs[-1][1] < min_gap:
            runs[-1] = (runs[-1][0], b)
        else:
            runs.append((a, b))
    return runs
