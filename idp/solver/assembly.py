"""Sparse assembly of the Newton matrix on the free degrees of freedom.

The elastic + mass part has a fixed pattern: it is built once, and every Newton iteration
only scatters new element values into it with compiled loops (no COO→CSR rebuild).
Contact Hessians (whose pattern changes with the active set) are added on top.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp


@numba.njit(cache=True)
def _scatter_add(out: np.ndarray, index: np.ndarray, values: np.ndarray, weight: float) -> None:  # pragma: no cover
    """out[index[k]] += weight·values[k] (serial: 4× faster than np.bincount with weights here)."""
    for k in range(index.size):
        out[index[k]] += weight * values[k]


@numba.njit(cache=True, parallel=True)
def _scatter_vertex_blocks(out, base, stride, blocks, weight, bounds):  # pragma: no cover
    """Add weight·blocks[e] (nv·d × nv·d) into a block CSR: the (a, b) vertex block of element e starts at
    base[e, a, b] (< 0: pinned, skipped) and its rows are stride[e, a, b] apart. Several threads without
    races: thread t adds only the blocks whose position lies in [bounds[t], bounds[t+1]) (boundaries between
    block rows, so a block never straddles two ranges); every thread reads all blocks, writes its own rows."""
    g, nv = base.shape[0], base.shape[1]
    d = blocks.shape[1] // nv
    for t in numba.prange(bounds.size - 1):
        lo, hi = bounds[t], bounds[t + 1]
        for e in range(g):
            for a in range(nv):
                for b in range(nv):
                    p0 = base[e, a, b]
                    if p0 < lo or p0 >= hi:
                        continue
                    st = stride[e, a, b]
                    for i in range(d):
                        for j in range(d):
                            out[p0 + i * st + j] += weight * blocks[e, a * d + i, b * d + j]


class FreeDofMap:
    """Maps global DOFs (vertex·d + coordinate) to the numbering of the free (unpinned) DOFs."""

    def __init__(self, free_mask: np.ndarray):
        self.free_mask = np.asarray(free_mask, dtype=bool)
        self.global_to_free = np.full(self.free_mask.size, -1, dtype=np.int64)
        self.free_dofs = np.flatnonzero(self.free_mask)
        self.global_to_free[self.free_dofs] = np.arange(self.free_dofs.size)

    @property
    def num_free(self) -> int:
        return int(self.free_dofs.size)


class FixedPatternAssembler:
    """Assembles Σ_e H_e (element blocks) + diag(d) into a CSR matrix with a pattern fixed at construction."""

    # exactly one of the two scatter maps is set: per vertex block (with its layout) or per DOF
    layout: BlockLayout | None
    _block_scatter: list[tuple[np.ndarray, np.ndarray]] | None
    _element_scatter: list[np.ndarray] | None

    def __init__(
        self,
        element_dofs: list[np.ndarray],
        dof_map: FreeDofMap,
        dim: int | None = None,
        positions: np.ndarray | None = None,
    ):
        """``element_dofs``: per energy, (m, k) global DOFs of each element (vertex·d + coordinate).
        With ``dim`` given and whole vertices pinned, the pattern is built per vertex block, which needs
        d² times less memory than building it per DOF. ``positions`` (n, d): where the vertices are, to split
        them into compact parts for :meth:`fused_scatter` (index ranges without them)."""
        self.dof_map = dof_map
        n = dof_map.num_free
        self.shape = (n, n)
        self._element_vertices: list[np.ndarray] | None = None
        self._positions = None if positions is None else np.asarray(positions, dtype=float)
        self._fused: dict[int, tuple] = {}
        if dim is not None and _pins_whole_vertices(dof_map.free_mask, dim):
            self._build_blocks(element_dofs, dof_map, dim)
            self._element_vertices = [np.ascontiguousarray(dofs[:, ::dim] // dim) for dofs in element_dofs]
        else:
            self._build_generic(element_dofs, dof_map)

    def _build_blocks(self, element_dofs: list[np.ndarray], dof_map: FreeDofMap, d: int) -> None:
        """Vertex-level pattern expanded to d×d blocks (every vertex fully free or fully pinned)."""
        vfree = dof_map.free_mask.reshape(-1, d)[:, 0]
        fv = np.full(vfree.size, -1, dtype=np.int64)
        nfv = int(vfree.sum())
        fv[vfree] = np.arange(nfv)
        pair_keys = []
        for dofs in element_dofs:
            L = fv[dofs[:, ::d] // d]  # (m, nv) free-vertex ids
            keys = L[:, :, None] * nfv + L[:, None, :]
            keys[(L[:, :, None] < 0) | (L[:, None, :] < 0)] = -1
            pair_keys.append(keys)
        diag_keys = np.arange(nfv, dtype=np.int64) * (nfv + 1)
        ukeys = np.unique(np.concatenate([k.ravel() for k in pair_keys] + [diag_keys]))
        ukeys = ukeys[ukeys >= 0]
        layout = BlockLayout(ukeys, nfv, d)
        self.layout = layout
        nnz = layout.nnz
        self.nnz = nnz
        itype = np.int32 if nnz < 2**31 - 1 else np.int64
        self.indptr, self.indices = layout.indptr, layout.indices
        vrow, vptr, deg = layout.vrow, layout.vptr, layout.deg
        a = np.arange(d)

        def block_positions(vkeys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            e = np.searchsorted(ukeys, vkeys)
            i = vrow[e]
            return (d * d * vptr[i] + d * (e - vptr[i])).astype(itype), (d * deg[i]).astype(itype)

        # per element vertex pair (a, b): CSR position of its block's entry (0, 0) (−1: pinned) and the
        # row stride; d² times smaller than a per-entry index (bunnyx30_13K: 9.5 MB instead of 43 MB)
        self._block_scatter = []
        for keys in pair_keys:
            valid = keys >= 0
            base = np.full(keys.shape, -1, dtype=itype)
            stride = np.zeros(keys.shape, dtype=itype)
            base[valid], stride[valid] = block_positions(keys[valid])
            self._block_scatter.append((base, stride))
        self._element_scatter = None
        # row ranges of the parallel scatter: one per numba thread, cut at block-row boundaries
        threads = max(1, numba.get_num_threads())
        cuts = np.linspace(0, nfv, threads + 1).astype(np.int64)
        self._scatter_bounds = (d * d * vptr[cuts]).astype(np.int64)
        dbase, dstride = block_positions(diag_keys)
        self._diag_scatter = (dbase[:, None] + a[None, :] * dstride[:, None] + a[None, :]).ravel()

    def _build_generic(self, element_dofs: list[np.ndarray], dof_map: FreeDofMap) -> None:
        """DOF-level pattern (any pinning); memory ~ several × m·k² int64 during construction."""
        self.layout = None
        self._block_scatter = None
        n = dof_map.num_free
        key_parts = []
        for dofs in element_dofs:
            local = dof_map.global_to_free[dofs]  # (m, k), -1 for pinned DOFs
            keys = (local[:, :, None] * n + local[:, None, :]).reshape(-1)
            keys[((local[:, :, None] < 0) | (local[:, None, :] < 0)).reshape(-1)] = -1
            key_parts.append(keys)
        diag = np.arange(n, dtype=np.int64) * (n + 1)
        all_keys = np.concatenate([*key_parts, diag])
        del key_parts
        unique_keys, scatter = np.unique(all_keys, return_inverse=True)
        del all_keys
        has_pinned = unique_keys.size and unique_keys[0] < 0
        if has_pinned:  # entries touching a pinned DOF go to a dummy slot (index nnz) that is dropped
            unique_keys = unique_keys[1:]
            scatter -= 1
            scatter[scatter < 0] = unique_keys.size
        self.nnz = int(unique_keys.size)
        scatter = scatter.astype(np.int32 if self.nnz < 2**31 - 1 else np.int64)
        self.indices = (unique_keys % n).astype(np.int32)
        self.indptr = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(np.bincount(unique_keys // n, minlength=n), out=self.indptr[1:])
        sizes = [d.shape[0] * d.shape[1] ** 2 for d in element_dofs]
        offsets = np.cumsum([0, *sizes])
        self._element_scatter = [scatter[offsets[i] : offsets[i + 1]] for i in range(len(element_dofs))]
        self._diag_scatter = scatter[offsets[-1] :]

    def fused_scatter(self, energy_index: int) -> tuple | None:
        """What a kernel needs to add the element blocks of energy ``energy_index`` straight into the values
        (block layout only, else None): (owner of every vertex, part pointers, elements of each part, base,
        stride); see :func:`idp.energies._elastic_kernels.element_terms_scatter`. The vertices are split into one
        part per numba thread by recursive coordinate bisection (``positions``), so few elements span two parts
        (bunny_3376: 5 % with two parts, against 60 % for two index ranges); each part lists the elements having
        a vertex in it, in increasing order. Built once per energy."""
        if self._block_scatter is None or self._element_vertices is None:
            return None
        cached = self._fused.get(energy_index)
        if cached is None:
            ev = self._element_vertices[energy_index]
            nparts = max(1, numba.get_num_threads())
            n = int(ev.max()) + 1 if ev.size else 0
            owner = _vertex_parts(self._positions, n, np.unique(ev), nparts)
            lists = [np.flatnonzero((owner[ev] == p).any(axis=1)) for p in range(nparts)]
            ptr = np.zeros(nparts + 1, dtype=np.int64)
            np.cumsum([a.size for a in lists], out=ptr[1:])
            base, stride = self._block_scatter[energy_index]
            elements = np.concatenate(lists).astype(np.int64) if lists else np.zeros(0, np.int64)
            cached = self._fused[energy_index] = (owner, ptr, elements, base, stride)
        return cached

    def start_data(self, diagonal: np.ndarray) -> np.ndarray:
        """A value array holding diag(``diagonal``); add element blocks with :meth:`add_element_blocks`
        and pass it to :meth:`finish_data`."""
        data = np.zeros(self.nnz + 1)  # last slot: entries that touch pinned DOFs
        _scatter_add(data, self._diag_scatter, np.ascontiguousarray(diagonal, dtype=float), 1.0)
        return data

    def add_element_blocks(
        self, data: np.ndarray, energy_index: int, first: int, blocks: np.ndarray, weight: float
    ) -> None:
        """Scatter ``blocks`` (g, k, k) of elements first … first+g−1 of energy ``energy_index``."""
        blocks = np.ascontiguousarray(blocks, dtype=float)
        if self._block_scatter is not None:
            base, stride = self._block_scatter[energy_index]
            g = blocks.shape[0]
            _scatter_vertex_blocks(
                data, base[first : first + g], stride[first : first + g], blocks, float(weight), self._scatter_bounds
            )
            return
        assert self._element_scatter is not None  # built per DOF when not per vertex block
        kk = blocks.shape[1] * blocks.shape[2]
        idx = self._element_scatter[energy_index][first * kk : (first + blocks.shape[0]) * kk]
        _scatter_add(data, idx, blocks.reshape(-1), float(weight))

    def finish_data(self, data: np.ndarray) -> np.ndarray:
        return data[: self.nnz]

    def assemble_data(self, element_blocks: list[np.ndarray], weights: list[float], diagonal: np.ndarray) -> np.ndarray:
        """Values of Σ_i weights[i]·blocks[i] + diag(``diagonal``) on the fixed pattern."""
        data = self.start_data(diagonal)
        for i, (blocks, w) in enumerate(zip(element_blocks, weights, strict=True)):
            self.add_element_blocks(data, i, 0, blocks, w)
        return self.finish_data(data)

    def assemble(self, element_blocks: list[np.ndarray], weights: list[float], diagonal: np.ndarray) -> sp.csr_matrix:
        """Σ_i weights[i]·blocks[i] scattered into the pattern, plus ``diagonal`` (free DOFs)."""
        data = self.assemble_data(element_blocks, weights, diagonal)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


class BlockLayout:
    """CSR arrays of a matrix made of full d×d blocks at the sorted vertex-pair ``keys`` (row·nfv + col).

    Rows of vertex i are d consecutive CSR rows of length d·deg(i); entry (a, b) of the block at
    ``keys[e]`` (row vertex i) sits at d²·vptr[i] + a·d·deg(i) + d·(e − vptr[i]) + b."""

    def __init__(self, keys: np.ndarray, nfv: int, d: int):
        self.keys, self.nfv, self.d = keys, nfv, d
        self.vrow = keys // nfv
        vcol = keys % nfv
        self.vptr = np.zeros(nfv + 1, dtype=np.int64)
        np.cumsum(np.bincount(self.vrow, minlength=nfv), out=self.vptr[1:])
        self.deg = np.diff(self.vptr)
        self.nnz = int(d * d * keys.size)
        itype = np.int32 if self.nnz < 2**31 - 1 else np.int64
        a = np.arange(d)
        self.indptr = np.empty(nfv * d + 1, dtype=itype)
        self.indptr[:-1] = (d * d * self.vptr[:-1, None] + a[None, :] * d * self.deg[:, None]).ravel()
        self.indptr[-1] = self.nnz
        self.indices = np.empty(self.nnz, dtype=np.int32)
        # one (row a, column b) entry of every block at a time: index temporaries of keys.size, not of nnz
        # (at bunnyx30_13K the full (blocks, d, d) int64 positions were 2 × 19 MB while the factor was alive)
        first, stride = self.block_starts(np.arange(keys.size))
        col = (d * vcol).astype(np.int32)
        for r in range(d):
            for c in range(d):
                self.indices[first + (r * stride + c)] = col + c
        # never changed after this: the linear solver then keeps these arrays as the pattern it analysed, not copies
        self.indptr.flags.writeable = False
        self.indices.flags.writeable = False

    def block_starts(self, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CSR position of entry (0, 0) of each given block and its row stride: entry (a, b) sits at
        first + a·stride + b."""
        i = self.vrow[blocks]
        return self.d * self.d * self.vptr[i] + self.d * (blocks - self.vptr[i]), self.d * self.deg[i]

    def positions(self, blocks: np.ndarray) -> np.ndarray:
        """(len(blocks), d, d) CSR positions of the entries of the given block indices."""
        d, a = self.d, np.arange(self.d)
        i = self.vrow[blocks]
        base = d * d * self.vptr[i] + d * (blocks - self.vptr[i])
        return base[:, None, None] + a[None, :, None] * (d * self.deg[i])[:, None, None] + a[None, None, :]

    def entry_positions(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CSR position of each DOF entry (rows[k], cols[k]) and whether its block is in the layout."""
        d = self.d
        vk = (rows // d) * self.nfv + cols // d
        e = np.searchsorted(self.keys, vk)
        found = e < self.keys.size
        found[found] = self.keys[e[found]] == vk[found]
        e = np.where(found, e, 0)
        i = self.vrow[e] if self.keys.size else e
        pos = d * d * self.vptr[i] + (rows % d) * d * self.deg[i] + d * (e - self.vptr[i]) + cols % d
        return pos, found


def _vertex_parts(positions: np.ndarray | None, n: int, used: np.ndarray, nparts: int) -> np.ndarray:
    """Part (0 … nparts−1) of each of the first n vertices: the ``used`` ones split by recursive bisection at the
    median of the longest axis of ``positions`` into parts of equal size (without positions: equal runs of
    ``used``), the others in part 0."""
    owner = np.zeros(n, dtype=np.int64)
    if positions is None or positions.shape[0] < n:
        if used.size:
            owner[used] = np.minimum(np.arange(used.size) * nparts // used.size, nparts - 1)
        return owner
    pos = positions

    def split(idx: np.ndarray, parts: int, first: int) -> None:
        if parts == 1 or idx.size == 0:
            owner[idx] = first
            return
        p = pos[idx]
        axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
        order = idx[np.argsort(p[:, axis], kind="stable")]
        low = parts // 2
        cut = idx.size * low // parts
        split(order[:cut], low, first)
        split(order[cut:], parts - low, first + low)

    split(used, nparts, 0)
    return owner


def _pins_whole_vertices(free_mask: np.ndarray, dim: int) -> bool:
    """True when every vertex has all its DOFs free or all pinned."""
    per_vertex = free_mask.reshape(-1, dim)
    return bool(np.all(per_vertex.all(axis=1) | ~per_vertex.any(axis=1)))


def restrict_collision_hessian(H: sp.spmatrix, collision_dof_to_free: np.ndarray, n_free: int) -> sp.csr_matrix:
    """Map a Hessian on collision-mesh DOFs to the free-DOF numbering, dropping pinned DOFs."""
    H = H.tocoo()
    r = collision_dof_to_free[H.row]
    c = collision_dof_to_free[H.col]
    keep = (r >= 0) & (c >= 0)
    return sp.csr_matrix((H.data[keep], (r[keep], c[keep])), shape=(n_free, n_free))
