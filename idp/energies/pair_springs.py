"""Zero-length springs between vertex pairs that change from step to step ("sticky" contact, paper §7.5 Fig. 21).

E(x) = (k/2) Σ_{(a,b) ∈ links} ‖x_a − x_b‖². It is **not part of the paper's energy**: the authors' dumplings-on-a-
plate run links contacting primitives of the wrappers and the pusher by weak springs so that they stick; idp
offers the same as an opt-in term. A zero-length spring attracts; the IPC barrier balances it before the
surfaces touch, and the CCD-filtered line search keeps every iterate intersection-free as for any other term.

The term is quadratic: its Hessian k·[[I, −I], [−I, I]] per link is constant and PSD (no projection needed). The
links change between steps, so the term cannot join the fixed element pattern; its Hessian goes in as vertex-pair
blocks beside the contact blocks (:meth:`hessian_blocks`), whose pattern grows with the pairs it sees.
"""

from __future__ import annotations

import numpy as np


class PairSprings:
    """Zero-length springs of stiffness ``stiffness`` between the vertex pairs of :attr:`pairs` ((m, 2) global ids)."""

    def __init__(self, dim: int, stiffness: float) -> None:
        if not (np.isfinite(stiffness) and stiffness > 0.0):
            raise ValueError(f"pair spring stiffness must be positive and finite, got {stiffness}")
        self.dim = int(dim)
        self.stiffness = float(stiffness)
        self.pairs = np.zeros((0, 2), dtype=np.int64)

    def set_pairs(self, pairs: np.ndarray) -> None:
        """Replace the linked vertex pairs ((m, 2) global vertex ids, a ≠ b)."""
        p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        if np.any(p[:, 0] == p[:, 1]):
            raise ValueError("a pair spring needs two different vertices")
        self.pairs = np.ascontiguousarray(p)

    def _differences(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        return x[self.pairs[:, 0]] - x[self.pairs[:, 1]]

    def value(self, x: np.ndarray) -> float:
        if self.pairs.shape[0] == 0:
            return 0.0
        d = self._differences(x)
        return 0.5 * self.stiffness * float(np.einsum("ij,ij->", d, d))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·d,) gradient: +k(x_a − x_b) at a, −k(x_a − x_b) at b."""
        x = np.asarray(x, dtype=np.float64)
        g = np.zeros((x.size // self.dim, self.dim))
        if self.pairs.shape[0]:
            f = self.stiffness * self._differences(x)
            np.add.at(g, self.pairs[:, 0], f)
            np.add.at(g, self.pairs[:, 1], -f)
        return g.reshape(-1)

    def hessian_blocks(self, vertex_to_free: np.ndarray, width: int, scale: float) -> tuple[np.ndarray, np.ndarray]:
        """``scale`` · Hessian as per-link blocks for the contact pattern: (m, 4) free-vertex ids (−1 padded, the
        free vertices first) and (m, width, width) blocks whose leading d·n × d·n part belongs to those n ≤ 2
        vertices. Links with no free vertex are dropped; a link with one free vertex keeps its k·I block."""
        d = self.dim
        if self.pairs.shape[0] == 0:
            return np.full((0, 4), -1, np.int32), np.zeros((0, width, width))
        fa = vertex_to_free[self.pairs[:, 0]]
        fb = vertex_to_free[self.pairs[:, 1]]
        both = (fa >= 0) & (fb >= 0)
        one = (fa >= 0) ^ (fb >= 0)
        m2, m1 = int(both.sum()), int(one.sum())
        verts = np.full((m2 + m1, 4), -1, np.int32)
        verts[:m2, 0], verts[:m2, 1] = fa[both], fb[both]
        verts[m2:, 0] = np.maximum(fa[one], fb[one])
        blocks = np.zeros((m2 + m1, width, width))
        k = scale * self.stiffness
        eye = np.eye(d)
        blocks[:, :d, :d] = k * eye
        blocks[:m2, d : 2 * d, d : 2 * d] = k * eye
        blocks[:m2, :d, d : 2 * d] = -k * eye
        blocks[:m2, d : 2 * d, :d] = -k * eye
        return verts, blocks

    def hessian(self, num_vertices: int):
        """The full (n·d, n·d) sparse Hessian (for tests and the dense fallback)."""
        import scipy.sparse as sp

        d, n = self.dim, int(num_vertices)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        rows, cols, vals = [], [], []
        for c in range(d):
            for p, q, s in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
                rows.append(p * d + c)
                cols.append(q * d + c)
                vals.append(np.full(p.size, s * self.stiffness))
        if not rows:
            return sp.csr_matrix((n * d, n * d))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n * d, n * d))
