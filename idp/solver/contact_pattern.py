"""Newton-matrix pattern = fixed elastic blocks ∪ contact couplings, grown only when a contact needs it.

Every new contact coupling between two free vertices changes the sparsity pattern, and each pattern
change costs a fill-reducing ordering plus a symbolic factorisation (at bunny_1922: ~30 ms against
~15 ms for the numeric factorisation itself). Measured on bunny_1922: the active set gained new
couplings in 250 of 290 Newton iterations, usually only 1–9 vertex pairs, and those pairs were not
within 20 d̂ when the pattern was last grown (so padding the pattern with nearby pairs does not help).

So this pattern (1) keeps the couplings it has seen, dropping stale ones only when they outnumber the
live ones (their entries are explicit zeros meanwhile, which only cost fill), and (2) folds a few
missing couplings into the diagonal instead of growing (see :meth:`GrowingBlockPattern._fold`): the
matrix is then a positive-definite majorant of the Hessian, which keeps the Newton direction a descent
direction. bunny_1922: 250 → 18 analyses, same Newton iteration count, 31.5 s → 22.6 s; bunny_3376
(with the size-scaled fold limit): 78 s → 45 s. A fold stiffens the pair's common motion (both sides moving
together costs what their closing costs), so where that motion matters (light petals sagging onto each other) the
folded direction can be far from Newton's: the Newton loop then grows the pattern at once
(``StepSolver._undistorted``, ``NewtonSettings.fold_distortion``).

Only for systems whose vertices are wholly free or wholly pinned (the block layout of
:class:`~idp.solver.assembly.FixedPatternAssembler`); values are exact, only the pattern is padded.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

from idp.solver.assembly import BlockLayout
from idp.thread_choice import ThreadChoice


@numba.njit(cache=True)
def _scatter_csc(
    cptr, crow, cval, dof_map, indptr, indices, out, missing_rows, missing_cols, missing_vals
):  # pragma: no cover
    """out[CSR position of (map[j], map[i])] += value of CSC entry (i, j), for a symmetric matrix whose CSC
    rows are sorted and ``dof_map`` is increasing on kept DOFs: one merge walk per column, no search.
    Entries whose position is absent are listed in missing_* (up to their length); returns their count."""
    n_missing = 0
    for j in range(cptr.size - 1):
        fj = dof_map[j]
        if fj < 0:
            continue
        p, end = indptr[fj], indptr[fj + 1]
        for k in range(cptr[j], cptr[j + 1]):
            fi = dof_map[crow[k]]
            if fi < 0:
                continue
            while p < end and indices[p] < fi:
                p += 1
            if p < end and indices[p] == fi:
                out[p] += cval[k]
            else:
                if n_missing < missing_rows.size:
                    missing_rows[n_missing] = fj
                    missing_cols[n_missing] = fi
                    missing_vals[n_missing] = cval[k]
                n_missing += 1
    return n_missing


@numba.njit(cache=True)
def _scatter_blocks(block_verts, blocks, keys, vptr, deg, nfv, d, out, missing):  # pragma: no cover
    """out[...] += every d×d vertex-pair block of the per-collision ``blocks`` (leading block of the
    collision's kept vertices ``block_verts``, −1 padded) at its place in the block layout. Pairs whose
    block is absent are listed in ``missing`` rows [collision, a, b] (up to its length); returns their count."""
    n_missing = 0
    for c in range(block_verts.shape[0]):
        for a in range(block_verts.shape[1]):
            va = block_verts[c, a]
            if va < 0:
                break
            lo, hi = vptr[va], vptr[va + 1]
            stride = d * deg[va]
            for b in range(block_verts.shape[1]):
                vb = block_verts[c, b]
                if vb < 0:
                    break
                key = va * nfv + vb
                l, h = lo, hi
                while l < h:
                    mid = (l + h) // 2
                    if keys[mid] < key:
                        l = mid + 1
                    else:
                        h = mid
                if l < hi and keys[l] == key:
                    base = d * d * vptr[va] + d * (l - vptr[va])
                    for r in range(d):
                        for s in range(d):
                            out[base + r * stride + s] += blocks[c, d * a + r, d * b + s]
                else:
                    if n_missing < missing.shape[0]:
                        missing[n_missing, 0] = c
                        missing[n_missing, 1] = a
                        missing[n_missing, 2] = b
                    n_missing += 1
    return n_missing


@numba.njit(cache=True, parallel=True)
def _scatter_blocks_parts(
    block_verts, blocks, keys, vptr, deg, nfv, d, out, owner, missing, counts
):  # pragma: no cover
    """:func:`_scatter_blocks` on several threads: part p adds only the rows of the vertices with owner p (so no
    two threads write one entry, and each entry still gets its collisions in increasing order), and lists its
    absent pairs in missing[p] (up to its length), their number in counts[p]."""
    for p in numba.prange(missing.shape[0]):
        n_missing = 0
        for c in range(block_verts.shape[0]):
            for a in range(block_verts.shape[1]):
                va = block_verts[c, a]
                if va < 0:
                    break
                if owner[va] != p:
                    continue
                lo, hi = vptr[va], vptr[va + 1]
                stride = d * deg[va]
                for b in range(block_verts.shape[1]):
                    vb = block_verts[c, b]
                    if vb < 0:
                        break
                    key = va * nfv + vb
                    l, h = lo, hi
                    while l < h:
                        mid = (l + h) // 2
                        if keys[mid] < key:
                            l = mid + 1
                        else:
                            h = mid
                    if l < hi and keys[l] == key:
                        base = d * d * vptr[va] + d * (l - vptr[va])
                        for r in range(d):
                            for s in range(d):
                                out[base + r * stride + s] += blocks[c, d * a + r, d * b + s]
                    else:
                        if n_missing < missing.shape[1]:
                            missing[p, n_missing, 0] = c
                            missing[p, n_missing, 1] = a
                            missing[p, n_missing, 2] = b
                        n_missing += 1
        counts[p] = n_missing


@numba.njit(cache=True)
def _embed_blocks(src, src_vptr, src_deg, dst_vptr, dst_deg, dst_block, d, dst):  # pragma: no cover
    """dst[...] = src[...] for every d×d block of a block layout, block e of ``src`` going to block
    ``dst_block[e]`` of the layout of ``dst`` (same block rows; < 0: not there, skipped): a per-block map instead
    of a per-entry one (at bunnyx30_13K 1.8 MB instead of 16 MB, alive all run)."""
    for i in range(src_vptr.size - 1):
        s_stride, t_stride = d * src_deg[i], d * dst_deg[i]
        for e in range(src_vptr[i], src_vptr[i + 1]):
            if dst_block[e] < 0:
                continue
            s0 = d * d * src_vptr[i] + d * (e - src_vptr[i])
            t0 = d * d * dst_vptr[i] + d * (dst_block[e] - dst_vptr[i])
            for a in range(d):
                for b in range(d):
                    dst[t0 + a * t_stride + b] = src[s0 + a * s_stride + b]


def _union_sorted(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sorted union of two sorted arrays of unique keys (``b``'s keys missing from ``a`` inserted into ``a``)."""
    if a.size == 0:
        return b
    pos = np.searchsorted(a, b)
    found = np.zeros(b.size, dtype=bool)
    inside = pos < a.size
    found[inside] = a[pos[inside]] == b[inside]
    return np.insert(a, pos[~found], b[~found])


#: collisions whose Hessian blocks are computed and added at a time (:meth:`GrowingBlockPattern.add_block_stream`):
#: a 9.4 MB buffer of 12 × 12 blocks
BLOCK_CHUNK = 8192


class _BlocksInMemory:
    """Blocks already computed, as :meth:`GrowingBlockPattern.add_block_stream` reads a stream (no copy)."""

    def __init__(self, block_verts: np.ndarray, blocks: np.ndarray):
        self.block_verts = block_verts
        self._blocks = blocks

    def __len__(self) -> int:
        return int(self.block_verts.shape[0])

    def blocks(self, c0: int, c1: int, buffer: np.ndarray) -> np.ndarray:
        return self._blocks[c0:c1]


class GrowingBlockPattern:
    """Assembles elastic values (on the base layout) plus contact COO entries into a padded block pattern."""

    def __init__(self, base: BlockLayout, stale_factor: float = 2.0, fold_limit: int | None = None):
        """``stale_factor``: when growing, keep the old extra couplings only while they number at most this
        many times the couplings needed now. ``fold_limit``: up to this many missing vertex-pair blocks are
        folded into the diagonal instead of growing the pattern (see :meth:`_fold`); default
        max(64, free vertices / 16). Measured (60 steps, fill at the end): bunny_3376 with 64 → 56 s,
        98.64–98.78 %; 256 → 45 s, 98.78 %; 512 → 42 s, 98.63 %; bunny_700 (865 vertices) with 256:
        97.57 % against 97.99 % with 64 — folding too large a share of the couplings slows the packing."""
        self.base = base
        self.stale_factor = float(stale_factor)
        self.fold_limit = max(64, base.nfv // 16) if fold_limit is None else int(fold_limit)
        self.folds = 0
        # False: missing couplings always grow the pattern (the Newton loop turns folding off for the rest of a step
        # after repeated distorted folds in a large system: StepSolver._fold_distorts, NewtonSettings.fold_stop_after)
        self.folding = True
        self._correction: tuple | None = None  # exact − folded matrix after a fold, as (values, rows, cols, n) ...
        self._correction_matrix: sp.csr_matrix | None = None  # ... and as a matrix once asked for
        self._folded: tuple | None = None  # (folded values, folded vertex-pair keys) for exact_matrix()
        self.extra = np.zeros(0, dtype=np.int64)  # vertex-pair keys outside the base pattern
        self.layout = base
        self._base_to_full: np.ndarray | None = None
        self.growths = 0
        # contact blocks are added on one thread per part of the rows (equal runs of vertices)
        self._parts = max(1, min(numba.get_num_threads(), base.nfv))
        self._owner = np.minimum(np.arange(base.nfv) * self._parts // max(base.nfv, 1), self._parts - 1)
        self._scatter_threads = ThreadChoice()  # one thread or one per part, whichever is faster here

    @property
    def last_folded(self) -> bool:
        """Whether the last assembled matrix is a folded majorant (``fold_correction`` holds exact − it)."""
        return self._correction is not None

    @property
    def fold_correction(self) -> sp.csr_matrix | None:
        """Exact − folded matrix of the last assembly (None when it was not folded), built when first asked for:
        only the exact direction at a folded iterate that looks converged needs it (bunny_700: building it at
        each of 163 folds took 0.07 s of a 6 s run)."""
        if self._correction is not None and self._correction_matrix is None:
            vals, rows, cols, n = self._correction
            self._correction_matrix = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
        return self._correction_matrix

    @fold_correction.setter
    def fold_correction(self, value: None) -> None:
        if value is not None:
            raise ValueError("fold_correction is set by a fold only")
        self._correction = self._correction_matrix = None

    def _matrix(self, data: np.ndarray) -> sp.csr_matrix:
        L = self.layout
        n = L.nfv * L.d
        return sp.csr_matrix((data, L.indices, L.indptr), shape=(n, n))

    def _vertex_keys(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        d, nfv = self.base.d, self.base.nfv
        return (rows // d) * nfv + cols // d

    def _outside_base(self, vkeys: np.ndarray) -> np.ndarray:
        keys = self.base.keys
        vkeys = np.unique(vkeys)
        e = np.minimum(np.searchsorted(keys, vkeys), max(keys.size - 1, 0))
        return vkeys[keys[e] != vkeys] if keys.size else vkeys

    def _grow(self, C: sp.csc_matrix, dof_map: np.ndarray, every_entry: bool = False) -> None:
        """Add the couplings of ``C`` that the pattern lacks; drop stale ones when they outnumber the live.

        The live couplings are read from the first entry of each d×d block (contact Hessian blocks are
        dense), or from every entry with ``every_entry``."""
        d = self.base.d
        if every_entry:
            first = C.tocoo()
            rows, cols = dof_map[first.row], dof_map[first.col]
        else:
            first = C[::d, ::d].tocoo()
            rows, cols = dof_map[first.row * d], dof_map[first.col * d]
        keep = (rows >= 0) & (cols >= 0)
        self._grow_keys(self._vertex_keys(rows[keep], cols[keep]))

    def _grow_keys(self, vertex_keys: np.ndarray) -> None:
        """Add the vertex-pair couplings ``vertex_keys`` (row·nfv + col) that the pattern lacks; drop stale
        extra couplings when they outnumber the live ones."""
        live = self._outside_base(vertex_keys)
        union = _union_sorted(self.extra, live)
        self._set_extra(union if union.size <= self.stale_factor * max(live.size, 1) else live)

    def _set_extra(self, extra: np.ndarray) -> None:
        """New layout = base ∪ ``extra`` couplings (sorted, unique and outside the base)."""
        self.extra = extra
        base = self.base.keys
        # the extra keys are outside the base: the union is an insertion, and base key e lands at e + (extra keys
        # below it) (instead of np.union1d's hashing of both: a growth at the Fig. 12 cat 20 → 9 ms, with the
        # union in _grow_keys)
        full = np.insert(base, np.searchsorted(base, extra), extra)
        self.layout, self._base_to_full = self.base, None  # the old layout's arrays are freed before the new are built
        self.layout = BlockLayout(full, self.base.nfv, self.base.d)
        # block of the new layout per base block
        self._base_to_full = np.arange(base.size, dtype=np.int64) + np.searchsorted(extra, base)
        self.growths += 1

    def _fold(self, data: np.ndarray, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> bool:
        """Replace a few missing off-diagonal blocks B_ij by |B_ij| = (B_ij B_ijᵀ)^½ on the diagonal block of vertex i
        (and so |B_ijᵀ| = (B_ijᵀ B_ij)^½ on that of j, from the mirrored block).

        With B = U S Vᵀ, [[U S Uᵀ, −B],[−Bᵀ, V S Vᵀ]] = [U; −V] S [U; −V]ᵀ ⪰ 0, so the result majorises the
        matrix: it stays positive definite and the Newton direction stays a descent direction (a slightly more
        cautious one); it avoids a new ordering and symbolic analysis for a handful of new couplings. The
        correction it leaves (exact − folded) has the rank of B per pair, where ‖B‖·I on both diagonal blocks left
        up to 2d − 1: fewer conjugate-gradient iterations for the exact direction (``idp.solver.pcg``)."""
        if not self.folding:
            return False
        d = self.base.d
        keys, inv = np.unique(self._vertex_keys(rows, cols), return_inverse=True)
        if keys.size > self.fold_limit:
            return False
        # several collisions may couple the same two vertices: |B| must be that of their *sum*, so add the entries
        # first, into one dense d×d block per vertex pair
        n = self.base.nfv * d
        entry, einv = np.unique(rows * n + cols, return_inverse=True)
        summed = np.bincount(einv, weights=vals, minlength=entry.size)
        entry_key = inv[np.unique(einv, return_index=True)[1]]
        B = np.zeros((keys.size, d, d))
        B[entry_key, (entry // n) % d, (entry % n) % d] = summed
        U, S, _ = np.linalg.svd(B)
        P = np.einsum("kab,kb,kcb->kac", U, S, U)  # (B Bᵀ)^½ per pair
        vi = keys // self.base.nfv
        a = np.arange(d)
        prow = np.broadcast_to((vi[:, None] * d + a[None, :])[:, :, None], P.shape).ravel()
        pcol = np.broadcast_to((vi[:, None] * d + a[None, :])[:, None, :], P.shape).ravel()
        pos, found = self.layout.entry_positions(prow, pcol)
        assert found.all(), "diagonal blocks are always in the pattern"
        np.add.at(data, pos, P.ravel())
        self._correction = (
            np.concatenate([vals, -P.ravel()]),
            np.concatenate([rows, prow]),
            np.concatenate([cols, pcol]),
            n,
        )
        self._correction_matrix = None
        self._folded = (data, keys)
        self.folds += 1
        return True

    def state(self) -> dict[str, np.ndarray]:
        """What the pattern has accumulated (the extra couplings, its counters), for a run's checkpoint: the
        pattern decides which couplings are folded and the fill-reducing ordering, so a resumed run needs it
        to take the very iterates of an uninterrupted one."""
        return {"extra": self.extra.copy(), "counters": np.array([self.folds, self.growths], dtype=np.int64)}

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`state` (nothing when ``state`` is empty: a checkpoint written before it existed)."""
        extra = state.get("extra")
        if extra is None:
            return
        if np.asarray(extra).dtype.kind not in "iu":
            raise ValueError("the checkpoint's contact pattern is not integer keys")
        extra = np.asarray(extra, dtype=np.int64).reshape(-1)
        n = self.base.nfv
        if extra.size and (extra.min() < 0 or extra.max() >= n * n or np.any(np.diff(extra) <= 0)):
            raise ValueError("the checkpoint's contact pattern does not fit this scene")
        self._set_extra(self._outside_base(extra))
        counters = state.get("counters")
        if counters is not None and np.asarray(counters).shape == (2,) and np.asarray(counters).dtype.kind in "iu":
            self.folds, self.growths = (int(v) for v in counters)

    def _full_data(self, base_data: np.ndarray) -> np.ndarray:
        """The base values on the current (possibly grown) layout, zeros at the extra couplings."""
        if self._base_to_full is None:
            return base_data.copy()
        data = np.zeros(self.layout.nnz)
        B, L = self.base, self.layout
        _embed_blocks(base_data, B.vptr, B.deg, L.vptr, L.deg, self._base_to_full, B.d, data)
        return data

    def assemble(
        self,
        base_data: np.ndarray,
        contact: sp.csc_matrix | None = None,
        dof_map: np.ndarray | None = None,
    ) -> sp.csr_matrix:
        """CSR of the base values plus the symmetric ``contact`` matrix, whose DOF j is free DOF
        ``dof_map[j]`` (< 0: pinned, dropped; increasing on the others). Matrices assembled on one
        pattern have equal ``indptr``/``indices``."""
        self.fold_correction = None
        self._folded = None
        data = self._full_data(base_data)
        if contact is not None and contact.nnz:
            C = contact.tocsc()
            C.sort_indices()
            cptr, crow = C.indptr, C.indices  # native dtype: an int64 copy costs ≈ 30 MB at bunnyx30_13K
            dof_map = np.asarray(dof_map, dtype=np.int64)
            L = self.layout
            none, nonef = np.zeros(0, dtype=np.int64), np.zeros(0)
            missing = _scatter_csc(cptr, crow, C.data, dof_map, L.indptr, L.indices, data, none, none, nonef)
            if missing:
                rows, cols = np.empty(missing, dtype=np.int64), np.empty(missing, dtype=np.int64)
                vals = np.empty(missing)
                del data  # stale values: freed before the new ones are allocated
                data = self._full_data(base_data)
                _scatter_csc(cptr, crow, C.data, dof_map, L.indptr, L.indices, data, rows, cols, vals)
                if not self._fold(data, rows, cols, vals):
                    for every_entry in (False, True):
                        self._grow(C, dof_map, every_entry)
                        L = self.layout
                        del data  # stale values: freed before the new ones are allocated
                        data = self._full_data(base_data)
                        if not _scatter_csc(cptr, crow, C.data, dof_map, L.indptr, L.indices, data, none, none, nonef):
                            break
                    else:
                        raise AssertionError("contact entries missing from the grown pattern")
        return self._matrix(data)

    def assemble_blocks(self, base_data: np.ndarray, block_verts: np.ndarray, blocks: np.ndarray) -> sp.csr_matrix:
        """CSR of the base values plus per-collision vertex blocks (``block_verts`` (m, 4) free-vertex ids,
        −1 padded; ``blocks`` (m, 12, 12), the leading d·n × d·n block of collision c belonging to its n
        vertices), with the same fold / grow policy as :meth:`assemble`: :meth:`add_block_stream` over blocks
        already computed."""
        return self.add_block_stream(self._full_data(base_data), _BlocksInMemory(block_verts, blocks))

    def embed(self, base_data: np.ndarray) -> np.ndarray:
        """The base values on the current layout for :meth:`add_block_stream`, which adds into them: ``base_data``
        itself (taken over, not copied) while the layout is the base pattern, else a new array (the caller may
        then drop ``base_data``: at bunnyx30_13K 16 MB not alive while the contact blocks are computed)."""
        if self._base_to_full is None:
            return base_data
        return self._full_data(base_data)

    def add_block_stream(self, data: np.ndarray, stream, chunk: int = BLOCK_CHUNK) -> sp.csr_matrix:
        """CSR of ``data`` (values on the current layout, from :meth:`embed`; added into) plus the per-collision
        blocks of ``stream`` (:class:`idp.contact.model.HessianBlockStream`, or blocks in memory): ``chunk``
        collisions at a time are computed into one buffer and added, so the blocks are never all alive.

        Vertex pairs absent from the layout are listed with their entries as they come; after the last range a few
        are folded onto the diagonal (:meth:`_fold`), more grow the layout: the values are carried over to the grown
        layout and the listed entries added in their order. Every entry thus receives its collisions in increasing
        order, whatever ``chunk`` and the thread count: the same sums, bit for bit, as adding all blocks at once
        (and, after a growth, as adding them all again on the grown layout)."""
        self.fold_correction = None
        self._folded = None
        m = len(stream)
        if m == 0:
            return self._matrix(data)
        d = self.base.d
        buffer = np.empty((min(chunk, m), 12, 12))
        listed: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for c0 in range(0, m, chunk):
            c1 = min(m, c0 + chunk)
            blocks = stream.blocks(c0, c1, buffer)
            bv = stream.block_verts[c0:c1]
            where = self._scatter_listing(bv, blocks, data)
            if where.shape[0]:
                c, a, b = where[:, 0], where[:, 1], where[:, 2]
                va, vb = bv[c, a].astype(np.int64), bv[c, b].astype(np.int64)
                r = np.arange(d)
                rows = np.broadcast_to((va[:, None, None] * d + r[None, :, None]), (c.size, d, d)).ravel()
                cols = np.broadcast_to((vb[:, None, None] * d + r[None, None, :]), (c.size, d, d)).ravel()
                ia = (a * d)[:, None, None] + r[None, :, None]
                ib = (b * d)[:, None, None] + r[None, None, :]
                listed.append((rows, cols, blocks[c[:, None, None], ia, ib].ravel()))
        del buffer
        if not listed:
            return self._matrix(data)
        rows, cols, vals = (np.concatenate(parts) for parts in zip(*listed, strict=True))
        del listed
        if self._fold(data, rows, cols, vals):
            return self._matrix(data)
        bv = stream.block_verts.astype(np.int64)
        pa = np.broadcast_to(bv[:, :, None], (bv.shape[0], 4, 4))
        pb = np.broadcast_to(bv[:, None, :], (bv.shape[0], 4, 4))
        live = (pa >= 0) & (pb >= 0)
        keys = pa[live] * self.base.nfv + pb[live]
        del bv, pa, pb, live
        old = self.layout
        old_keys, old_vptr, old_deg = old.keys, old.vptr, old.deg  # (the large index arrays are freed)
        del old
        self._grow_keys(keys)
        del keys
        # a stale coupling the growth dropped holds zero here (no block of this matrix couples its vertices, and
        # folds only touch diagonal blocks)
        return self._matrix(self._carry_over(data, old_keys, old_vptr, old_deg, rows, cols, vals))

    def _carry_over(
        self,
        data: np.ndarray,
        old_keys: np.ndarray,
        old_vptr: np.ndarray,
        old_deg: np.ndarray,
        rows: np.ndarray,
        cols: np.ndarray,
        vals: np.ndarray,
    ) -> np.ndarray:
        """Values on the current (just grown) layout: ``data``, on the layout of vertex-pair keys ``old_keys``
        (with its ``old_vptr``, ``old_deg``), copied block by block (blocks the growth dropped are skipped), plus the
        DOF entries (rows, cols, vals) added in their order; every entry must have its block in the layout."""
        new = self.layout
        where = np.searchsorted(new.keys, old_keys)
        kept = where < new.keys.size
        kept[kept] = new.keys[where[kept]] == old_keys[kept]
        grown = np.zeros(new.nnz)
        _embed_blocks(data, old_vptr, old_deg, new.vptr, new.deg, np.where(kept, where, -1), self.base.d, grown)
        del where, kept
        pos, found = new.entry_positions(rows, cols)
        if not found.all():
            raise AssertionError("entries missing from the grown pattern")
        np.add.at(grown, pos, vals)
        return grown

    def _scatter_listing(self, block_verts: np.ndarray, blocks: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Add the blocks into ``out``; return the absent vertex pairs as rows [collision, a, b], ordered by
        collision, then a, then b (as the serial loop finds them): on one thread, or on one per part of the rows,
        whichever :class:`~idp.thread_choice.ThreadChoice` finds faster here (the same sums and list either way)."""
        L = self.layout
        d, nfv = self.base.d, self.base.nfv
        cap = 16 * block_verts.shape[0]  # every pair of every collision: no list can overflow

        def on_one() -> np.ndarray:
            missing = np.empty((cap, 3), np.int64)
            n = _scatter_blocks(block_verts, blocks, L.keys, L.vptr, L.deg, nfv, d, out, missing)
            return missing[:n]

        if self._parts == 1:
            return on_one()
        return self._scatter_threads.run(
            block_verts.shape[0], lambda: self._scatter_parts(block_verts, blocks, out, cap), on_one
        )

    def _scatter_parts(self, block_verts: np.ndarray, blocks: np.ndarray, out: np.ndarray, cap: int) -> np.ndarray:
        """:meth:`_scatter_listing` on one thread per part of the rows."""
        L = self.layout
        d, nfv = self.base.d, self.base.nfv
        lists = np.empty((self._parts, cap, 3), np.int64)
        counts = np.zeros(self._parts, np.int64)
        _scatter_blocks_parts(block_verts, blocks, L.keys, L.vptr, L.deg, nfv, d, out, self._owner, lists, counts)
        if not counts.any():
            return np.zeros((0, 3), np.int64)
        found = np.concatenate([lists[p, : int(counts[p])] for p in range(self._parts)])
        return found[np.lexsort((found[:, 2], found[:, 1], found[:, 0]))]

    def exact_matrix(self) -> sp.csr_matrix:
        """The last (folded) matrix without folding, on the pattern grown by the folded couplings.

        Built from the folded values and the fold's own entries (the contact Hessian is not kept: at
        bunnyx30_13K it is ≈ 50–90 MB, alive during the factorisation otherwise)."""
        if self._folded is None:
            raise RuntimeError("exact_matrix() needs a folded matrix from the last assemble()")
        data, keys = self._folded
        assert self.fold_correction is not None  # set together with _folded by _fold()
        K = self.fold_correction.tocoo()
        old = self.layout
        self._set_extra(_union_sorted(self.extra, self._outside_base(keys)))
        exact = self._carry_over(
            data, old.keys, old.vptr, old.deg, K.row.astype(np.int64), K.col.astype(np.int64), K.data
        )
        self.fold_correction, self._folded = None, None
        return self._matrix(exact)
