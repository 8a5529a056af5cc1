"""Growing contact pattern: exact values when it grows, a PD majorant when it folds, stable arrays otherwise."""

import numpy as np
import pytest
import scipy.sparse as sp

from idp.solver.assembly import FixedPatternAssembler, FreeDofMap, restrict_collision_hessian
from idp.solver.contact_pattern import GrowingBlockPattern
from idp.thread_choice import ThreadChoice

DIM = 3


def _chain_problem(nv=24, pinned=(0, 23)):
    """Tets along a chain of vertices (so far-apart vertices are not coupled) with some pinned vertices."""
    rng = np.random.default_rng(0)
    verts = np.stack([np.arange(i, i + 4) for i in range(nv - 3)])
    dofs = (verts[:, :, None] * DIM + np.arange(DIM)).reshape(len(verts), -1)
    vfree = np.ones(nv, dtype=bool)
    vfree[list(pinned)] = False
    dmap = FreeDofMap(np.repeat(vfree, DIM))
    asm = FixedPatternAssembler([dofs], dmap, dim=DIM)
    A = rng.standard_normal((len(verts), 12, 12))
    blocks = np.einsum("mij,mkj->mik", A, A)  # PSD element blocks
    diag = 1.0 + rng.random(dmap.num_free)
    return rng, dmap, asm, blocks, diag


def _pair_hessian(rng, vertex_ids, nv, scale=10.0):
    """A PSD 'contact pair' Hessian coupling the given vertices, on all vertices' DOFs (CSC)."""
    k = len(vertex_ids) * DIM
    B = rng.standard_normal((2, k))
    local = scale * B.T @ B
    idx = (np.asarray(vertex_ids)[:, None] * DIM + np.arange(DIM)).ravel()
    r, c = np.meshgrid(idx, idx, indexing="ij")
    return sp.csc_matrix((local.ravel(), (r.ravel(), c.ravel())), shape=(nv * DIM, nv * DIM))


def _reference(asm, blocks, diag, C, dmap):
    H = asm.assemble([blocks], [1.0], diag)
    return (H + restrict_collision_hessian(C, dmap.global_to_free, dmap.num_free)).toarray()


def test_grown_pattern_gives_the_exact_matrix_and_keeps_arrays_while_unchanged():
    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0)  # never fold: always exact
    data = asm.assemble_data([blocks], [1.0], diag)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24) + _pair_hessian(rng, [0, 20, 21, 22], 24)  # 0 is pinned
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.growths == 1
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))
    # the same couplings again: same pattern arrays, no growth
    M2 = pattern.assemble(data, 2 * C, dmap.global_to_free)
    assert np.array_equal(M2.indices, M.indices) and np.array_equal(M2.indptr, M.indptr) and pattern.growths == 1
    assert np.allclose(M2.toarray(), _reference(asm, blocks, diag, 2 * C, dmap))
    # no contact at all: still the grown pattern (zeros there), values equal the elastic part
    M3 = pattern.assemble(data)
    assert np.array_equal(M3.indices, M.indices)
    assert np.allclose(M3.toarray(), asm.assemble([blocks], [1.0], diag).toarray())


def test_csr_is_canonical_for_the_solver():
    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0)
    M = pattern.assemble(
        asm.assemble_data([blocks], [1.0], diag), _pair_hessian(rng, [3, 12, 13, 14], 24), dmap.global_to_free
    )
    S = M.copy()
    S.sort_indices()
    assert np.array_equal(S.indices, M.indices)
    assert abs(M - M.T).max() <= 1e-12 * abs(M).max()


@pytest.mark.parametrize("seed", range(4))
def test_folded_couplings_give_a_positive_definite_majorant(seed):
    rng, dmap, asm, blocks, diag = _chain_problem()
    rng = np.random.default_rng(seed)
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    data = asm.assemble_data([blocks], [1.0], diag)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24, scale=1e3)
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.folds == 1 and pattern.growths == 0
    assert np.array_equal(M.indices, asm.layout.indices)  # pattern unchanged
    exact = _reference(asm, blocks, diag, C, dmap)
    gap = M.toarray() - exact
    assert np.linalg.eigvalsh(gap).min() > -1e-9 * np.abs(exact).max()  # M ⪰ exact Hessian
    assert np.linalg.eigvalsh(M.toarray()).min() > 0
    # only the blocks of vertices in the missing couplings change
    touched = np.zeros(dmap.num_free, dtype=bool)
    for v in (2, 15, 16, 17):
        touched[dmap.global_to_free[v * DIM : v * DIM + DIM]] = True
    assert np.allclose(gap[~touched][:, ~touched], 0)


def test_too_many_missing_couplings_grow_the_pattern_instead_of_folding():
    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=4)
    data = asm.assemble_data([blocks], [1.0], diag)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24)  # 3 far pairs → 6 missing vertex-pair blocks > 4
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.growths == 1 and pattern.folds == 0
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))


def test_stale_couplings_are_dropped_but_live_ones_kept():
    rng, dmap, asm, blocks, diag = _chain_problem(nv=40, pinned=(0,))
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0, stale_factor=2.0)
    data = asm.assemble_data([blocks], [1.0], diag)
    many = sum((_pair_hessian(rng, [v, v + 20], 40) for v in range(1, 15)), sp.csc_matrix((120, 120)))
    pattern.assemble(data, many, dmap.global_to_free)
    grown = pattern.layout.keys.size
    # one old coupling still live plus one new one: the 13 stale ones are dropped, the live one kept
    C = _pair_hessian(rng, [1, 21], 40) + _pair_hessian(rng, [3, 30], 40)
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.growths == 2 and pattern.layout.keys.size < grown
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))


def test_sparse_contact_blocks_still_end_up_in_the_pattern():
    """A contact block whose first entry is structurally absent is found by the every-entry fallback."""
    rng, dmap, asm, blocks, diag = _chain_problem(nv=40, pinned=(0,))
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0)
    data = asm.assemble_data([blocks], [1.0], diag)
    many = sum((_pair_hessian(rng, [v, v + 20], 40) for v in range(1, 15)), sp.csc_matrix((120, 120)))
    pattern.assemble(data, many, dmap.global_to_free)
    C = (_pair_hessian(rng, [1, 21], 40) + _pair_hessian(rng, [3, 30], 40)).tolil()
    C[3, 63] = C[63, 3] = 0.0  # (vertex 1, x) × (vertex 21, x): first entry of a live block removed
    C = C.tocsc()
    C.eliminate_zeros()
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))


def test_exact_matrix_after_a_fold_equals_the_unfolded_matrix():
    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    data = asm.assemble_data([blocks], [1.0], diag)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24, scale=1e3)
    pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.last_folded
    M = pattern.exact_matrix()
    assert not pattern.last_folded and pattern.growths == 1 and pattern.fold_limit == 64
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))


def _collision_blocks(rng, groups, dmap, nv, scale=10.0):
    """Per-collision blocks on free vertices (as the compiled barrier gives them) and the same Hessian as a
    CSC on all vertices' DOFs (as ipctk gives it)."""
    vfree = dmap.global_to_free[::DIM] >= 0
    block_verts = np.full((len(groups), 4), -1, dtype=np.int32)
    blocks = np.zeros((len(groups), 12, 12))
    C = sp.csc_matrix((nv * DIM, nv * DIM))
    for c, verts in enumerate(groups):
        kept = [v for v in verts if vfree[v]]
        k = len(kept) * DIM
        B = rng.standard_normal((2, k))
        local = scale * B.T @ B
        block_verts[c, : len(kept)] = [dmap.global_to_free[v * DIM] // DIM for v in kept]
        blocks[c, :k, :k] = local
        idx = (np.asarray(kept)[:, None] * DIM + np.arange(DIM)).ravel()
        r, cc = np.meshgrid(idx, idx, indexing="ij")
        C = C + sp.csc_matrix((local.ravel(), (r.ravel(), cc.ravel())), shape=C.shape)
    return block_verts, blocks, C


@pytest.mark.parametrize("fold_limit", [0, 4, 64])
def test_collision_blocks_assemble_like_the_contact_matrix(fold_limit):
    """assemble_blocks (compiled barrier) and assemble (a CSC contact Hessian) give the same matrix,
    whether the couplings fit, are folded or grow the pattern; and the same exact matrix after a fold."""
    rng, dmap, asm, blocks, diag = _chain_problem()
    groups = [[2, 15, 16, 17], [0, 20, 21, 22], [5, 6], [9, 10, 11]]  # 0 is pinned
    bv, cb, C = _collision_blocks(rng, groups, dmap, 24, scale=1e3)
    data = asm.assemble_data([blocks], [1.0], diag)
    p_blocks = GrowingBlockPattern(asm.layout, fold_limit=fold_limit)
    p_csc = GrowingBlockPattern(asm.layout, fold_limit=fold_limit)
    Mb = p_blocks.assemble_blocks(data, bv, cb)
    Mc = p_csc.assemble(data, C, dmap.global_to_free)
    assert (p_blocks.folds, p_blocks.growths) == (p_csc.folds, p_csc.growths)
    assert np.array_equal(Mb.indices, Mc.indices) and np.array_equal(Mb.indptr, Mc.indptr)
    assert np.allclose(Mb.toarray(), Mc.toarray(), rtol=1e-12, atol=1e-9)
    if p_blocks.last_folded:
        assert np.allclose(p_blocks.exact_matrix().toarray(), _reference(asm, blocks, diag, C, dmap))
    else:
        assert np.allclose(Mb.toarray(), _reference(asm, blocks, diag, C, dmap))


def test_many_missing_collision_blocks_grow_the_pattern_exactly():
    """More missing pairs than the first scatter has room for (the pass that lists them all)."""
    rng, dmap, asm, blocks, diag = _chain_problem(nv=120, pinned=(0,))
    groups = [list(rng.choice(np.arange(1, 120), 4, replace=False)) for _ in range(150)]  # ~2,000 missing pairs
    bv, cb, C = _collision_blocks(rng, groups, dmap, 120)
    data = asm.assemble_data([blocks], [1.0], diag)
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0)
    M = pattern.assemble_blocks(data, bv, cb)
    assert pattern.growths == 1
    assert np.allclose(M.toarray(), _reference(asm, blocks, diag, C, dmap))


def test_folding_bounds_the_sum_of_collisions_that_share_a_coupling():
    """Two collision blocks coupling the same two far-apart vertices: the fold must bound their summed coupling
    (root of the summed squares of the separate blocks is too small for rank-one blocks that add up), and it adds
    no more than that coupling needs: M − exact has its rank, one (a multiple of the identity on both diagonal
    blocks would leave five)."""
    _rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    data = asm.assemble_data([blocks], [1.0], diag)
    n = np.array([0.6, 0.0, 0.8])
    u = np.concatenate([n, -n])
    block = np.zeros((12, 12))
    block[:6, :6] = 1e3 * np.outer(u, u)  # rank one, PSD: pushes the two vertices apart along n
    free = dmap.global_to_free[::DIM] // DIM
    verts = np.array([[free[2], free[15], -1, -1]] * 2, dtype=np.int32)
    M = pattern.assemble_blocks(data, verts, np.stack([block, block]))
    assert pattern.folds == 1
    exact = asm.assemble([blocks], [1.0], diag).toarray()
    for a, b in ((0, 0), (0, 1), (1, 0), (1, 1)):
        ra = free[(2, 15)[a]] * DIM + np.arange(DIM)
        rb = free[(2, 15)[b]] * DIM + np.arange(DIM)
        exact[np.ix_(ra, rb)] += 2 * block[a * DIM : a * DIM + DIM, b * DIM : b * DIM + DIM]
    gap = M.toarray() - exact
    ev = np.linalg.eigvalsh(gap)
    assert ev.min() > -1e-9 * np.abs(exact).max()  # M ⪰ exact Hessian
    assert np.count_nonzero(ev > 1e-9 * np.abs(exact).max()) == 1
    # B = 2 · (−1e3 n nᵀ), σ(B) = 2e3; [U; −V] S [U; −V]ᵀ has the one eigenvalue σ(B)·(|u|² + |v|²) = 2σ(B)
    assert ev.max() == pytest.approx(2 * 2e3, rel=1e-9)


@pytest.mark.parametrize("fold_limit", [0, 10_000])
def test_block_scatter_on_several_threads_equals_the_serial_one(fold_limit):
    """assemble_blocks with the rows split over threads: the same matrix values, bit for bit, the same folds and
    the same growth as on one thread (each entry gets its collisions in the same order)."""
    import numba

    rng, _, asm, blocks, diag = _chain_problem(nv=40, pinned=(0, 39))
    data = asm.assemble_data([blocks], [1.0], diag)
    nfv = asm.layout.nfv
    m = 60
    bv = np.full((m, 4), -1, np.int32)
    for c in range(m):
        k = 1 + c % 4
        bv[c, :k] = rng.choice(nfv, size=k, replace=False)
    A = rng.standard_normal((m, 12, 12))
    cblocks = np.einsum("mij,mkj->mik", A, A)
    results = []
    before = numba.get_num_threads()
    for threads, way in ((1, None), (2, True), (2, False)):
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        try:
            pattern = GrowingBlockPattern(asm.layout, fold_limit=fold_limit)
            if way is not None:  # the thread choice's either way, not its timing
                pattern._scatter_threads = ThreadChoice(force=way)
            M = pattern.assemble_blocks(data, bv, cblocks)
            K = pattern.fold_correction
        finally:
            numba.set_num_threads(before)
        results.append((M, None if K is None else K.toarray(), pattern.growths, pattern.folds))
    M1, K1, g1, f1 = results[0]
    for M2, K2, g2, f2 in results[1:]:
        assert np.array_equal(M1.indptr, M2.indptr) and np.array_equal(M1.indices, M2.indices)
        np.testing.assert_array_equal(M1.data, M2.data)
        assert (g1, f1) == (g2, f2) == ((1, 0) if fold_limit == 0 else (0, 1))
        assert (K1 is None) == (K2 is None)
        if K1 is not None:
            np.testing.assert_array_equal(K1, K2)


def _random_collision_blocks(rng, nfv: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """m collisions of 1–4 distinct free vertices with symmetric PSD 12 × 12 blocks."""
    bv = np.full((m, 4), -1, np.int32)
    for c in range(m):
        k = 1 + c % 4
        bv[c, :k] = rng.choice(nfv, size=k, replace=False)
    A = rng.standard_normal((m, 12, 12))
    return bv, np.einsum("mij,mkj->mik", A, A)


class _Stream:
    """Blocks handed out a range at a time through the caller's buffer, as the contact model's stream does."""

    def __init__(self, bv: np.ndarray, blocks: np.ndarray):
        self._bv, self._blocks = bv, blocks
        self.block_verts = np.full_like(bv, -7)  # written range by range, as the contact model's
        self.ranges: list[tuple[int, int]] = []

    def __len__(self) -> int:
        return self._bv.shape[0]

    def blocks(self, c0, c1, buffer):
        self.ranges.append((c0, c1))
        self.block_verts[c0:c1] = self._bv[c0:c1]
        buffer[: c1 - c0] = self._blocks[c0:c1]
        return buffer[: c1 - c0]


@pytest.mark.parametrize("fold_limit", [0, 10_000])
@pytest.mark.parametrize("chunk", [1, 7, 60])
def test_blocks_added_a_range_at_a_time_equal_all_at_once(chunk, fold_limit):
    """add_block_stream over ranges of `chunk` collisions: the matrix of adding every block at once, bit for bit,
    the same fold or growth; after a growth, the values carried over plus the listed entries equal the same blocks
    added again on the grown layout (each entry gets its collisions in increasing order either way)."""
    rng, _, asm, blocks, diag = _chain_problem(nv=40, pinned=(0, 39))
    data = asm.assemble_data([blocks], [1.0], diag)
    bv, cblocks = _random_collision_blocks(rng, asm.layout.nfv, 60)
    whole = GrowingBlockPattern(asm.layout, fold_limit=fold_limit)
    M_whole = whole.assemble_blocks(data, bv, cblocks)
    pattern = GrowingBlockPattern(asm.layout, fold_limit=fold_limit)
    stream = _Stream(bv, cblocks)
    M = pattern.add_block_stream(pattern.embed(data.copy()), stream, chunk=chunk)
    assert stream.ranges == [(c, min(60, c + chunk)) for c in range(0, 60, chunk)]
    assert (pattern.growths, pattern.folds) == (whole.growths, whole.folds) == ((1, 0) if fold_limit == 0 else (0, 1))
    assert np.array_equal(M.indptr, M_whole.indptr) and np.array_equal(M.indices, M_whole.indices)
    np.testing.assert_array_equal(M.data, M_whole.data)
    if fold_limit == 0:  # grown: the same blocks again on the grown layout find every pair
        again = pattern.add_block_stream(pattern.embed(data.copy()), _Stream(bv, cblocks), chunk=chunk)
        assert pattern.growths == 1
        np.testing.assert_array_equal(M.data, again.data)


def test_a_growth_that_drops_stale_couplings_carries_the_live_values_over():
    """A second set of collisions far from the first: the growth keeps only the live couplings (the stale ones
    outnumber them), so blocks of the old layout have no place in the new one; the matrix equals the same blocks
    added on a pattern that only ever saw the second set."""
    rng, _, asm, blocks, diag = _chain_problem(nv=40, pinned=(0, 39))
    data = asm.assemble_data([blocks], [1.0], diag)
    assert asm.layout.nfv > 33  # the free vertices the collisions below name
    first = np.array([[a, b, -1, -1] for a, b in zip(range(0, 10), range(20, 30), strict=True)], np.int32)
    second = np.array([[5, 33, -1, -1]], np.int32)
    A = rng.standard_normal((11, 12, 12))
    spd = np.einsum("mij,mkj->mik", A, A)
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0, stale_factor=2.0)
    pattern.add_block_stream(pattern.embed(data.copy()), _Stream(first, spd[:10]), chunk=3)
    extra_before = pattern.extra.size
    M = pattern.add_block_stream(pattern.embed(data.copy()), _Stream(second, spd[10:]), chunk=3)
    assert pattern.growths == 2 and pattern.extra.size < extra_before  # the stale couplings were dropped
    fresh = GrowingBlockPattern(asm.layout, fold_limit=0, stale_factor=2.0)
    F = fresh.add_block_stream(fresh.embed(data.copy()), _Stream(second, spd[10:]))
    assert np.array_equal(M.indptr, F.indptr) and np.array_equal(M.indices, F.indices)
    np.testing.assert_array_equal(M.data, F.data)
