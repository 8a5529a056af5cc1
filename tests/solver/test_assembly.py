"""Sparse assembly: the fixed-pattern scatter and the contact restriction equal a dense reference."""

import numpy as np
import pytest
import scipy.sparse as sp

from idp.solver.assembly import FixedPatternAssembler, FreeDofMap, restrict_collision_hessian


def test_fixed_pattern_assembly_matches_dense():
    rng = np.random.default_rng(0)
    n_vert, m, k = 12, 10, 6
    dofs = np.stack([rng.choice(n_vert * 2, size=k, replace=False) for _ in range(m)])
    free = np.ones(n_vert * 2, dtype=bool)
    free[[0, 5, 7]] = False
    dmap = FreeDofMap(free)
    asm = FixedPatternAssembler([dofs], dmap)
    blocks = rng.standard_normal((m, k, k))
    diag = rng.random(dmap.num_free)
    H = asm.assemble([blocks], [0.5], diag).toarray()
    A = np.zeros((free.size, free.size))
    for e in range(m):
        A[np.ix_(dofs[e], dofs[e])] += 0.5 * blocks[e]
    ref = A[np.ix_(dmap.free_dofs, dmap.free_dofs)] + np.diag(diag)
    assert np.allclose(H, ref)
    # same pattern, new values: only values change
    H2 = asm.assemble([2 * blocks], [0.5], diag)
    assert np.allclose(H2.toarray() - np.diag(diag), 2 * (ref - np.diag(diag)))


@pytest.mark.parametrize("dim", [2, 3])
def test_vertex_block_pattern_matches_dof_pattern(dim):
    """Whole-vertex pinning uses the block construction: same matrix as the DOF-level one, CSR canonical."""
    rng = np.random.default_rng(dim)
    nv, m = 30, 40
    verts = np.stack([rng.choice(nv, size=dim + 1, replace=False) for _ in range(m)])
    dofs = (verts[:, :, None] * dim + np.arange(dim)).reshape(m, -1)
    pinned_vertices = np.zeros(nv, dtype=bool)
    pinned_vertices[[2, 11, 17]] = True
    free = np.repeat(~pinned_vertices, dim)
    dmap = FreeDofMap(free)
    blocks = rng.standard_normal((m, dofs.shape[1], dofs.shape[1]))
    diag = rng.random(dmap.num_free)
    block_asm = FixedPatternAssembler([dofs], dmap, dim=dim)
    generic = FixedPatternAssembler([dofs], dmap)
    Hb = block_asm.assemble([blocks], [0.7], diag)
    Hg = generic.assemble([blocks], [0.7], diag)
    assert np.allclose(Hb.toarray(), Hg.toarray())
    assert Hb.has_sorted_indices or np.all(np.diff(Hb.indices[Hb.indptr[0] : Hb.indptr[1]]) > 0)
    Hs = Hb.copy()
    Hs.sort_indices()
    assert np.array_equal(Hs.indices, Hb.indices)  # already sorted: CHOLMOD gets canonical CSR


def test_collision_hessian_restricted_to_free_dofs():
    Hc = sp.random(6, 6, density=0.6, random_state=2, format="csc")
    to_free = np.array([0, -1, 1, 2, -1, 3])
    R = restrict_collision_hessian(Hc, to_free, 4).toarray()
    dense = Hc.toarray()
    keep = np.flatnonzero(to_free >= 0)
    assert np.allclose(R, dense[np.ix_(keep, keep)])


@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("model", ["neo_hookean", "stvk"])
def test_fused_elastic_scatter_equals_kernel_then_scatter(threads, model):
    """ElasticEnergy.gradient_hessian_into (element kernel and scatter in one pass, vertices split into parts)
    gives the gradient and matrix values of the element kernel followed by the assembler's scatter, bit for bit,
    for any number of parts."""
    import numba

    from idp.energies.elastic import ElasticEnergy
    from idp.mesh.generate import tet_box

    mesh = tet_box((0, 0, 0), (1, 1, 2), (3, 3, 5))
    X, T = mesh.vertices, mesh.elements
    rng = np.random.default_rng(threads)
    x = X * np.array([1.0, 0.9, 0.7]) + 0.02 * rng.standard_normal(X.shape)
    E = ElasticEnergy(model, X, T, 1e5, 0.45)
    pinned = X[:, 2] < 1e-9
    free = np.repeat(~pinned, 3)
    dmap = FreeDofMap(free)
    diag = rng.random(dmap.num_free)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        asm = FixedPatternAssembler([E.element_dofs()], dmap, dim=3, positions=X)
        parts = asm.fused_scatter(0)
    finally:
        numba.set_num_threads(before)
    assert parts is not None
    owner, ptr, elements = parts[0], parts[1], parts[2]
    assert ptr.size == min(threads, numba.config.NUMBA_NUM_THREADS) + 1
    for p in range(ptr.size - 1):  # every part lists, in order, the elements having a vertex in it
        listed = elements[ptr[p] : ptr[p + 1]]
        assert np.array_equal(listed, np.flatnonzero((owner[T] == p).any(axis=1)))
    ref = asm.start_data(diag)

    def sink(first, blocks):
        asm.add_element_blocks(ref, 0, first, blocks, 0.3)

    _, g_ref = E.value_gradient_hessian_groups(x, sink, project=True, group=50)
    data = asm.start_data(diag)
    g = E.gradient_hessian_into(x, parts, data, 0.3, project=True)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(asm.finish_data(data), asm.finish_data(ref))
