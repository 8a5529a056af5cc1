"""Springs between vertex pairs that change from step to step ("sticky" contact, paper §7.5 Fig. 21).

E(x) = (k/2) Σ_{(a,b) ∈ links} (‖x_a − x_b‖ − ℓ_ab)², with rest lengths ℓ_ab = 0 (zero-length springs that
attract, idp's relinking sticky contact) or the pair's distance when it was linked (springs that hold a contact
as it was, the authors' glue). It is **not part of the paper's energy**: the authors' dumplings-on-a-plate run
links contacting primitives of the wrappers and the pusher by weak springs so that they stick; idp offers the same
as an opt-in term. The IPC barrier balances the springs before surfaces touch, and the CCD-filtered line search
keeps every iterate intersection-free as for any other term.

Per link the Hessian is [[K, −K], [−K, K]] with K = k[(1 − ℓ/r)(I − n nᵀ) + n nᵀ] (r = ‖x_a − x_b‖, n their unit
direction); a compressed link (r < ℓ) has a negative transverse part, which the projection clamps to zero, so
every block is PSD. Zero-length links have the constant K = k I. The links change between steps, so the term
cannot join the fixed element pattern; its Hessian goes in as vertex-pair blocks beside the contact blocks
(:meth:`hessian_blocks`), whose pattern grows with the pairs it sees.
"""

from __future__ import annotations

import numpy as np

#: below this distance (in scene units, relative to nothing) a link's direction is taken as undefined
_TINY = 1e-300


class PairSprings:
    """Springs of stiffness ``stiffness`` between the vertex pairs of :attr:`pairs` ((m, 2) global ids), of rest
    lengths :attr:`rest_lengths` ((m,), zeros unless :meth:`set_pairs` was given some)."""

    def __init__(self, dim: int, stiffness: float) -> None:
        if not (np.isfinite(stiffness) and stiffness > 0.0):
            raise ValueError(f"pair spring stiffness must be positive and finite, got {stiffness}")
        self.dim = int(dim)
        self.stiffness = float(stiffness)
        self.pairs = np.zeros((0, 2), dtype=np.int64)
        self.rest_lengths = np.zeros(0)

    def set_pairs(self, pairs: np.ndarray, rest_lengths: np.ndarray | None = None) -> None:
        """Replace the linked vertex pairs ((m, 2) global vertex ids, a ≠ b) and their rest lengths ((m,), ≥ 0;
        zero-length springs when omitted)."""
        p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        if np.any(p[:, 0] == p[:, 1]):
            raise ValueError("a pair spring needs two different vertices")
        if rest_lengths is None:
            rl = np.zeros(p.shape[0])
        else:
            rl = np.asarray(rest_lengths, dtype=np.float64).reshape(-1)
            if rl.shape[0] != p.shape[0]:
                raise ValueError(f"pair springs: {rl.shape[0]} rest lengths for {p.shape[0]} pairs")
            if not np.all(np.isfinite(rl) & (rl >= 0.0)):
                raise ValueError("pair spring rest lengths must be finite and non-negative")
        self.pairs = np.ascontiguousarray(p)
        self.rest_lengths = np.ascontiguousarray(rl)

    def _differences(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        return x[self.pairs[:, 0]] - x[self.pairs[:, 1]]

    def _stretch(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(r − ℓ, r) per link, r = ‖d‖."""
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        return r - self.rest_lengths, r

    def value(self, x: np.ndarray) -> float:
        if self.pairs.shape[0] == 0:
            return 0.0
        d = self._differences(x)
        if not self.rest_lengths.any():
            return 0.5 * self.stiffness * float(np.einsum("ij,ij->", d, d))
        s, _ = self._stretch(d)
        return 0.5 * self.stiffness * float(s @ s)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Flat (n·d,) gradient: +k(r − ℓ) d/r at a, the opposite at b (k d for zero-length links)."""
        x = np.asarray(x, dtype=np.float64)
        g = np.zeros((x.size // self.dim, self.dim))
        if self.pairs.shape[0]:
            d = self._differences(x)
            f = self.stiffness * d
            if self.rest_lengths.any():
                s, r = self._stretch(d)
                f *= (s / np.maximum(r, _TINY))[:, None]
            np.add.at(g, self.pairs[:, 0], f)
            np.add.at(g, self.pairs[:, 1], -f)
        return g.reshape(-1)

    def link_hessians(self, x: np.ndarray) -> np.ndarray:
        """(m, d, d) projected per-link blocks K (the link's Hessian is [[K, −K], [−K, K]])."""
        m, dim = self.pairs.shape[0], self.dim
        K = np.broadcast_to(self.stiffness * np.eye(dim), (m, dim, dim)).copy()
        if m and self.rest_lengths.any():
            d = self._differences(x)
            _, r = self._stretch(d)
            n = d / np.maximum(r, _TINY)[:, None]
            nn = np.einsum("ia,ib->iab", n, n)
            transverse = np.maximum(0.0, 1.0 - self.rest_lengths / np.maximum(r, _TINY))
            K = self.stiffness * (transverse[:, None, None] * (np.eye(dim) - nn) + nn)
        return K

    def hessian_blocks(
        self, x: np.ndarray, vertex_to_free: np.ndarray, width: int, scale: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``scale`` · projected Hessian at ``x`` as per-link blocks for the contact pattern: (m, 4) free-vertex
        ids (−1 padded, the free vertices first) and (m, width, width) blocks whose leading d·n × d·n part belongs
        to those n ≤ 2 vertices. Links with no free vertex are dropped; a link with one free vertex keeps its K."""
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
        K = scale * self.link_hessians(x)
        Kb, K1 = K[both], K[one]
        blocks = np.zeros((m2 + m1, width, width))
        blocks[:m2, :d, :d] = Kb
        blocks[:m2, d : 2 * d, d : 2 * d] = Kb
        blocks[:m2, :d, d : 2 * d] = -Kb
        blocks[:m2, d : 2 * d, :d] = -Kb
        blocks[m2:, :d, :d] = K1
        return verts, blocks

    def hessian(self, x: np.ndarray):
        """The full (n·d, n·d) sparse projected Hessian at ``x`` (for tests and the dense fallback)."""
        import scipy.sparse as sp

        x = np.asarray(x, dtype=np.float64)
        d, n = self.dim, x.size // self.dim
        m = self.pairs.shape[0]
        if m == 0:
            return sp.csr_matrix((n * d, n * d))
        K = self.link_hessians(x)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        ia = (d * a[:, None] + np.arange(d)).reshape(m, d)
        ib = (d * b[:, None] + np.arange(d)).reshape(m, d)
        rows, cols, vals = [], [], []
        for p, q, sgn in ((ia, ia, 1.0), (ib, ib, 1.0), (ia, ib, -1.0), (ib, ia, -1.0)):
            rows.append(np.repeat(p, d, axis=1).reshape(-1))
            cols.append(np.tile(q, (1, d)).reshape(-1))
            vals.append(sgn * K.reshape(-1))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n * d, n * d))
