"""Tests of idp.solver.linear (scipy fallback, factory) and the optional CHOLMOD backend."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, cast

import numpy as np
import pytest
import scipy.sparse as sp

from idp.errors import SolverError
from idp.solver.grid_matrices import grid_edges
from idp.solver.linear import (
    LinearSolver,
    NotPositiveDefinite,
    ScipySolver,
    available_solvers,
    have_pymetis,
    make_linear_solver,
    nested_dissection_ordering,
)

if TYPE_CHECKING:  # imported in the fixture, after the cvxopt importorskip
    from idp.solver.cholmod_cvxopt import CholmodSolver

# ----------------------------------------------------------------------------- matrices


def spd_blocks(rng: np.random.Generator, m: int, d: int) -> np.ndarray:
    G = rng.standard_normal((m, d, d))
    B = G @ G.transpose(0, 2, 1) + 0.1 * np.eye(d)
    return 0.5 * (B + B.transpose(0, 2, 1))


def edge_matrix(edges: np.ndarray, blocks: np.ndarray, nv: int, d: int) -> sp.csr_matrix:
    """Sum over edges (i, j) of [[B, -B], [-B, B]] placed on the DOFs of i and j (PSD)."""
    off = np.arange(d)
    di = edges[:, 0, None] * d + off
    dj = edges[:, 1, None] * d + off
    shape = blocks.shape

    def rc(r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.broadcast_to(r[:, :, None], shape).ravel(), np.broadcast_to(c[:, None, :], shape).ravel()

    parts = [rc(di, di), rc(dj, dj), rc(di, dj), rc(dj, di)]
    R = np.concatenate([p[0] for p in parts])
    C = np.concatenate([p[1] for p in parts])
    V = np.concatenate([blocks.ravel(), blocks.ravel(), -blocks.ravel(), -blocks.ravel()])
    return sp.csr_matrix((V, (R, C)), shape=(nv * d, nv * d))


def make_matrix(nx: int = 10, d: int = 3, seed: int = 0, contacts: int = 0) -> sp.csr_matrix:
    """Elasticity-like SPD block matrix on a tet grid: edge blocks + lumped mass (+ far contacts)."""
    rng = np.random.default_rng(seed)
    nv = nx**3
    E = grid_edges(nx)
    A = edge_matrix(E, spd_blocks(rng, len(E), d), nv, d) + sp.diags(rng.uniform(0.5, 1.5, nv * d))
    if contacts:
        crng = np.random.default_rng(1234)  # contact pairs independent of the value seed
        P = crng.integers(0, nv, (contacts, 2))
        P = P[np.abs(P[:, 0] - P[:, 1]) > nv // 3]  # far apart
        A = A + edge_matrix(P, spd_blocks(rng, len(P), d), nv, d)
    A = sp.csr_matrix(A)
    A.sort_indices()
    return A


def rel_residual(A: sp.spmatrix, x: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(A @ x - b) / np.linalg.norm(b))


# ----------------------------------------------------------------------------- fixtures


def _cholmod_solver(d: int, **kw: bool) -> CholmodSolver:
    pytest.importorskip("cvxopt", reason="cvxopt not importable: CHOLMOD backend (pip install idp[cholmod]) not tested")
    from idp.solver.cholmod_cvxopt import CholmodSolver

    return CholmodSolver(dofs_per_node=d, **kw)


def new_solver(name: str, d: int = 3) -> LinearSolver:
    if name == "cholmod":
        return _cholmod_solver(d)
    if name == "cholmod-amd":
        return _cholmod_solver(d, use_metis=False)
    if name == "scipy":
        return ScipySolver(dofs_per_node=d)
    if name == "scipy-mmd":
        return ScipySolver(dofs_per_node=d, use_metis=False)
    raise AssertionError(name)


BACKENDS = ["cholmod", "cholmod-amd", "scipy", "scipy-mmd"]


@pytest.fixture(scope="module")
def A0() -> sp.csr_matrix:
    return make_matrix(10, 3, seed=0)


@pytest.fixture(scope="module")
def A0_contact() -> sp.csr_matrix:
    return make_matrix(10, 3, seed=0, contacts=60)


# ----------------------------------------------------------------------------- tests


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("fmt", ["csr", "csc"])
def test_solve_residual(backend: str, fmt: str, A0: sp.csr_matrix) -> None:
    s = new_solver(backend)
    A = A0.asformat(fmt)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    s.factorize(A)
    x = s.solve(b)
    assert x.shape == b.shape
    assert rel_residual(A0, x, b) < 1e-10
    assert s.stats["factorizations"] == 1 and s.stats["symbolic_analyses"] == 1
    assert s.stats["symbolic_reuses"] == 0
    for key in ("ordering", "symbolic", "numeric", "solve"):
        assert s.stats[key] >= 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_refactor_same_pattern_reuses_analysis(backend: str, A0: sp.csr_matrix) -> None:
    s = new_solver(backend)
    b = np.random.default_rng(2).standard_normal(A0.shape[0])
    s.factorize(A0)
    x0 = s.solve(b)
    A1 = make_matrix(10, 3, seed=7)  # same pattern, different values
    assert np.array_equal(A1.indices, A0.indices) and np.array_equal(A1.indptr, A0.indptr)
    s.factorize(A1)
    x1 = s.solve(b)
    assert s.stats["symbolic_analyses"] == 1
    assert s.stats["symbolic_reuses"] == 1
    assert s.stats["factorizations"] == 2
    assert rel_residual(A1, x1, b) < 1e-10
    assert np.linalg.norm(x1 - x0) > 1e-3 * np.linalg.norm(x0)  # new values were really used

    # Values changed in place in the caller's matrix (same arrays) must be picked up too.
    A2 = A1.copy()
    s.factorize(A2)
    A2.data *= 1.7
    s.factorize(A2)
    assert rel_residual(A2, s.solve(b), b) < 1e-10
    assert s.stats["symbolic_reuses"] == 3


@pytest.mark.parametrize("backend", BACKENDS)
def test_changed_pattern_triggers_new_analysis(backend: str, A0: sp.csr_matrix, A0_contact: sp.csr_matrix) -> None:
    assert A0_contact.nnz > A0.nnz
    s = new_solver(backend)
    b = np.random.default_rng(3).standard_normal(A0.shape[0])
    s.factorize(A0)
    s.factorize(A0_contact)
    assert s.stats["symbolic_analyses"] == 2 and s.stats["symbolic_reuses"] == 0
    assert rel_residual(A0_contact, s.solve(b), b) < 1e-10
    s.factorize(A0)  # contacts gone: pattern changes back
    if backend.startswith("cholmod"):  # a subset of the analysed pattern: the symbolic factor is reused
        assert s.stats["symbolic_analyses"] == 2 and s.stats["subset_reuses"] == 1
    else:
        assert s.stats["symbolic_analyses"] == 3
    assert rel_residual(A0, s.solve(b), b) < 1e-10
    analyses = s.stats["symbolic_analyses"]
    # Same n and nnz, different pattern (vertices renumbered): must not be mistaken for a reuse.
    vp = np.random.default_rng(8).permutation(A0.shape[0] // 3)
    p = (3 * vp[:, None] + np.arange(3)).ravel()
    Ap = sp.csr_matrix(A0[p][:, p])
    Ap.sort_indices()
    assert Ap.nnz == A0.nnz and not np.array_equal(Ap.indices, A0.indices)
    s.factorize(Ap)
    assert s.stats["symbolic_analyses"] == analyses + 1
    assert rel_residual(Ap, s.solve(b), b) < 1e-10


@pytest.mark.parametrize("backend", ["cholmod", "cholmod-amd"])
def test_cholmod_indefinite_raises_and_recovers(backend: str, A0: sp.csr_matrix) -> None:
    s = new_solver(backend)
    bad = A0.copy()
    bad[17, 17] = -1.0  # e_17^T A e_17 < 0: indefinite, same pattern
    with pytest.raises(NotPositiveDefinite):
        s.factorize(bad)
    with pytest.raises(SolverError):
        s.solve(np.ones(A0.shape[0]))
    # The symbolic analysis survives the failure and a good matrix factors again.
    s.factorize(A0)
    b = np.ones(A0.shape[0])
    assert rel_residual(A0, s.solve(b), b) < 1e-10
    assert s.stats["symbolic_reuses"] == 1
    assert issubclass(NotPositiveDefinite, SolverError)


@pytest.mark.parametrize("backend", ["scipy", "scipy-mmd"])
def test_scipy_indefinite_is_finite_or_raises(backend: str, A0: sp.csr_matrix) -> None:
    s = new_solver(backend)
    bad = A0.copy()
    bad[17, 17] = -1.0
    b = np.ones(A0.shape[0])
    try:
        s.factorize(bad)
        x = s.solve(b)
    except NotPositiveDefinite:
        return
    assert np.isfinite(x).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_singular_raises(backend: str) -> None:
    A = make_matrix(4, 3)
    A = A.tolil()
    A[5, :] = 0.0
    A[:, 5] = 0.0
    A = A.tocsr()  # row/col 5 is zero and no longer stored: structurally singular
    s = new_solver(backend)
    with pytest.raises(NotPositiveDefinite):
        s.factorize(A)
        s.solve(np.ones(A.shape[0]))


@pytest.mark.parametrize("backend", BACKENDS)
def test_non_finite_matrix_rejected(backend: str) -> None:
    A = make_matrix(4, 3)
    A.data[3] = np.nan
    with pytest.raises(SolverError):
        new_solver(backend).factorize(A)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("d", [2, 1, 7])
def test_other_dofs_per_node(backend: str, d: int) -> None:
    # d=7 on a 3-DOF matrix: n % 7 != 0, the ordering falls back to the scalar graph.
    A = make_matrix(8, 2 if d == 2 else 3, seed=4, contacts=20)
    s = new_solver(backend, d=d)
    b = np.random.default_rng(5).standard_normal(A.shape[0])
    s.factorize(A)
    assert rel_residual(A, s.solve(b), b) < 1e-10
    s.factorize(A * 2.0)
    assert s.stats["symbolic_reuses"] == 1
    assert rel_residual(A * 2.0, s.solve(b), b) < 1e-10


@pytest.mark.parametrize("backend", BACKENDS)
def test_multiple_rhs_and_unsorted_input(backend: str, A0: sp.csr_matrix) -> None:
    s = new_solver(backend)
    # A COO matrix with duplicate entries: converted and summed, not trusted as is.
    coo = A0.tocoo()
    half = np.r_[coo.data[:100] * 0.5, coo.data[100:]]
    dup = sp.coo_matrix(
        (np.r_[half, coo.data[:100] * 0.5], (np.r_[coo.row, coo.row[:100]], np.r_[coo.col, coo.col[:100]])),
        shape=A0.shape,
    )
    s.factorize(dup)
    B = np.random.default_rng(6).standard_normal((A0.shape[0], 3))
    X = s.solve(B)
    assert X.shape == B.shape
    assert np.linalg.norm(A0 @ X - B) / np.linalg.norm(B) < 1e-10
    with pytest.raises(ValueError):
        s.solve(np.ones(A0.shape[0] + 1))


def test_solve_before_factorize() -> None:
    with pytest.raises(SolverError):
        ScipySolver().solve(np.ones(3))


def test_nested_dissection_keeps_vertex_dofs_together(A0: sp.csr_matrix) -> None:
    if not have_pymetis():
        pytest.skip("pymetis not importable")
    n = A0.shape[0]
    p = nested_dissection_ordering(A0.indptr, A0.indices, n, 3)
    assert p.dtype == np.int64 and np.array_equal(np.sort(p), np.arange(n))
    blocks = p.reshape(-1, 3)
    assert np.all(blocks % 3 == [0, 1, 2]) and np.all(blocks // 3 == blocks[:, :1] // 3)
    assert not np.array_equal(p, np.arange(n))  # a real reordering


def test_cholmod_metis_ordering_beats_natural_fill(A0: sp.csr_matrix) -> None:
    """The METIS ordering must really be applied: its factor is much sparser than natural order's."""
    pytest.importorskip("cvxopt", reason="cvxopt not importable: CHOLMOD backend not tested")
    if not have_pymetis():
        pytest.skip("pymetis not importable")
    from cvxopt import cholmod

    s = _cholmod_solver(3)
    s.factorize(A0)
    nnz_metis = len(cholmod.getfactor(s._F))
    tril = sp.tril(A0).tocoo()
    import cvxopt

    S = cvxopt.spmatrix(tril.data.tolist(), tril.row.tolist(), tril.col.tolist(), A0.shape)
    saved = dict(cholmod.options)
    try:
        cholmod.options.update({"nmethods": 1, "supernodal": 2})
        F = cholmod.symbolic(S, p=cvxopt.matrix(np.arange(A0.shape[0])), uplo="L")
        cholmod.numeric(S, F)
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)
    assert nnz_metis < 0.6 * len(cholmod.getfactor(F))
    assert dict(cholmod.options) == saved  # our calls leave the global options alone


def test_unknown_name_lists_choices() -> None:
    with pytest.raises(ValueError) as info:
        make_linear_solver("nope")
    msg = str(info.value)
    assert "'nope'" in msg and "'auto'" in msg and "'cholmod'" in msg and "'scipy'" in msg


def test_factory_and_available() -> None:
    names = available_solvers()
    assert names[-1] == "scipy"
    s = make_linear_solver("scipy", dofs_per_node=2)
    assert isinstance(s, ScipySolver) and s.name == "scipy" and s.dofs_per_node == 2
    auto = make_linear_solver()
    assert auto.name == names[0]
    if "cholmod" in names:
        c = make_linear_solver("CHOLMOD", dofs_per_node=2)
        assert c.name == "cholmod" and c.dofs_per_node == 2
    with pytest.raises(ValueError):
        make_linear_solver("scipy", dofs_per_node=0)


def test_factory_without_cvxopt(monkeypatch: pytest.MonkeyPatch) -> None:
    """Simulate a missing cvxopt: 'auto' falls back to scipy, 'cholmod' explains how to install."""
    monkeypatch.setitem(sys.modules, "cvxopt", None)
    monkeypatch.setitem(sys.modules, "cvxopt.cholmod", None)
    monkeypatch.delitem(sys.modules, "idp.solver.cholmod_cvxopt", raising=False)
    assert available_solvers() == ["scipy"]
    assert make_linear_solver("auto").name == "scipy"
    with pytest.raises(SolverError, match=r"pip install idp\[cholmod\]"):
        make_linear_solver("cholmod")


def test_cholmod_reuse_ordering_option(A0: sp.csr_matrix, A0_contact: sp.csr_matrix) -> None:
    """Opt-in ordering reuse: a changed pattern of the same size keeps the old permutation."""
    if not have_pymetis():
        pytest.skip("pymetis not importable")
    s = _cholmod_solver(3, reuse_ordering=True)
    s.factorize(A0)
    p0 = s._perm
    s.factorize(A0_contact)
    assert s._perm is p0 and s.stats["symbolic_analyses"] == 2
    b = np.ones(A0.shape[0])
    assert rel_residual(A0_contact, s.solve(b), b) < 1e-10
    d = _cholmod_solver(3)  # default: a fresh ordering per pattern
    d.factorize(A0)
    q0 = d._perm
    d.factorize(A0_contact)
    assert d._perm is not None and q0 is not None
    assert not np.array_equal(d._perm, q0)


def test_cholmod_couplings_that_come_and_go_reuse_the_union_analysis(
    A0: sp.csr_matrix, A0_contact: sp.csr_matrix
) -> None:
    """Contacts appearing and disappearing: after the union is analysed, no further analysis is needed."""
    pytest.importorskip("cvxopt")
    s = _cholmod_solver(3)
    b = np.random.default_rng(5).standard_normal(A0.shape[0])
    for A in (A0, A0_contact, A0, A0_contact, A0):
        s.factorize(A)
        assert rel_residual(A, s.solve(b), b) < 1e-10
    assert s.stats["symbolic_analyses"] == 2
    assert s.stats["subset_reuses"] >= 2


def test_the_gradient_descent_scaling_is_finite_and_positive():
    from idp.solver.newton import _positive_scaling

    d = _positive_scaling(np.array([4.0, 0.0, -2.0, np.nan, 1e-30, np.inf]))
    assert np.all(np.isfinite(d)) and np.all(d > 0)
    assert d[0] == 4.0 and d[2] == 2.0 and d[1] == d[3] == d[4] == d[5] == 3.0  # the median of 4 and 2
    assert np.array_equal(_positive_scaling(np.zeros(3)), np.ones(3))
    # a p-norm energy's diagonal spans many orders of magnitude: every positive entry near the typical one is kept
    wide = np.array([1e25, 1e13, 2.0, 3.0, 5.0, 1e-3])
    assert np.array_equal(_positive_scaling(wide), wide)


def test_pattern_cache_keeps_frozen_layout_arrays_and_copies_writeable_ones():
    """A block layout's arrays are read-only: the cache keeps them (through scipy's views) instead of copies, and
    still sees a change of pattern; arrays a caller may change in place are copied."""
    from idp.solver.assembly import BlockLayout
    from idp.solver.linear import PatternCache

    layout = BlockLayout(np.array([0, 1, 2, 3], dtype=np.int64), 2, 3)
    A = sp.csr_matrix((np.ones(layout.nnz), layout.indices, layout.indptr), shape=(6, 6))
    cache = PatternCache()
    cache.store(A.indptr, A.indices)
    assert np.shares_memory(cache.indices, layout.indices)
    B = sp.csr_matrix((np.zeros(layout.nnz), layout.indices, layout.indptr), shape=(6, 6))
    assert cache.same(B.indptr, B.indices)
    other = BlockLayout(np.array([0, 3], dtype=np.int64), 2, 3)
    assert not cache.same(other.indptr, other.indices)

    indptr, indices = A.indptr.copy(), A.indices.copy()  # writeable: copied
    cache.store(indptr, indices)
    assert not np.shares_memory(cache.indices, indices)
    indices[0] = 5
    assert not cache.same(indptr, indices)


# ----------------------------------------------------------------------------- ordering choice (CHOLMOD backend)


def chain_matrix(nv: int = 400, d: int = 3, seed: int = 0) -> sp.csr_matrix:
    """A path of vertices (a block tridiagonal SPD matrix): minimum degree orders it without any fill."""
    rng = np.random.default_rng(seed)
    E = np.stack([np.arange(nv - 1), np.arange(1, nv)], axis=1)
    A = edge_matrix(E, spd_blocks(rng, nv - 1, d), nv, d) + sp.diags(rng.uniform(0.5, 1.5, nv * d))
    A = sp.csr_matrix(A)
    A.sort_indices()
    return A


@pytest.mark.parametrize(("matrix", "expected"), [("grid", "metis"), ("chain", "amd")])
def test_ordering_choice_follows_predicted_work(matrix: str, expected: str) -> None:
    """METIS for a volume grid (nested dissection needs far less work), AMD for a path (no fill at all); the chosen
    ordering's predicted flops are those of the better one within the margin."""
    pytest.importorskip("cvxopt", reason="cvxopt not importable: CHOLMOD backend not tested")
    if not have_pymetis():
        pytest.skip("pymetis not importable")
    from idp.solver.cholmod_cvxopt import AMD_MARGIN, amd_vertex_ordering, choose_ordering
    from idp.solver.linear import metis_vertex_ordering, vertex_graph
    from idp.solver.symbolic import cholesky_flops

    A = make_matrix(nx=12) if matrix == "grid" else chain_matrix()
    n = A.shape[0]
    xadj, adjncy = vertex_graph(A.indptr, A.indices, n, 3)
    nv = n // 3
    kind, vperm = choose_ordering(xadj, adjncy)
    assert kind == expected
    assert np.array_equal(np.sort(vperm), np.arange(nv))
    flops = {
        name: cholesky_flops(xadj, adjncy, nv, order(xadj, adjncy))
        for name, order in (("metis", metis_vertex_ordering), ("amd", amd_vertex_ordering))
    }
    assert cholesky_flops(xadj, adjncy, nv, vperm) <= AMD_MARGIN * min(flops.values())
    if matrix == "grid":
        assert flops["amd"] > 1.2 * flops["metis"]
    else:
        assert flops["amd"] == pytest.approx(sum(c * c for c in [2.0] * (nv - 1) + [1.0]))  # no fill: counts 2, …, 2, 1


def test_ordering_comparisons_thin_out_while_the_choice_holds() -> None:
    """The orderings are compared at the first analysis and after 4, 8, 16 … more while the choice stays; every
    pattern is still factorised correctly with the ordering in use."""
    pytest.importorskip("cvxopt", reason="cvxopt not importable: CHOLMOD backend not tested")
    if not have_pymetis():
        pytest.skip("pymetis not importable")
    from idp.solver.cholmod_cvxopt import ORDERING_RECHECK

    s = _cholmod_solver(3)
    s.union_growth = 0.0  # every new pattern analysed on its own
    rng = np.random.default_rng(3)
    base = chain_matrix(nv=300)
    analyses = 1 + ORDERING_RECHECK + 2 * ORDERING_RECHECK
    for k in range(analyses):
        P = np.array([[k, 150 + k]])  # one more coupling each time: a new pattern
        A = sp.csr_matrix(base + edge_matrix(P, spd_blocks(rng, 1, 3), 300, 3))
        A.sort_indices()
        s.factorize(A)
        b = rng.standard_normal(A.shape[0])
        assert rel_residual(A, s.solve(b), b) < 1e-10
    assert s.stats["symbolic_analyses"] == analyses
    assert s.stats["ordering_checks"] == 3  # analyses 1, 1 + 4 and 1 + 4 + 8
    assert s.stats["amd_orderings"] + s.stats.get("metis_orderings", 0) == analyses


def _ordering_of(solver: CholmodSolver) -> np.ndarray:
    """The DOF ordering of the solver's last analysis (idp orders: METIS or AMD)."""
    assert solver._perm is not None
    return solver._perm


@pytest.mark.parametrize("resume_at", [1, 3, 5])
def test_cholmod_state_lets_a_resumed_solver_make_the_same_choices(resume_at: int) -> None:
    """A run's checkpoint keeps the solver's ordering schedule and analysed pattern (CholmodSolver.state): a fresh
    solver that loads it and meets that pattern again takes the same ordering without counting an analysis, and
    from then on chooses its orderings (METIS or AMD, and when to compare them) as the uninterrupted solver does."""
    patterns = [make_matrix(nx=6, seed=0, contacts=c) for c in (0, 4, 8, 12, 16, 20, 24, 28)]  # growing
    whole = _cholmod_solver(3)
    resumed = None
    b = np.random.default_rng(5).standard_normal(patterns[0].shape[0])
    for k, A in enumerate(patterns):
        whole.factorize(A)
        if k == resume_at:  # the checkpoint, then a new process that resumes with the pattern it had reached
            resumed = _cholmod_solver(3)
            resumed.load_state(whole.state())
        if resumed is not None:
            resumed.factorize(A)
            assert np.array_equal(_ordering_of(resumed), _ordering_of(whole)), k
            assert resumed.state()["schedule"].tolist() == whole.state()["schedule"].tolist(), k
            assert np.allclose(resumed.solve(b), whole.solve(b), rtol=1e-10, atol=1e-12)
    assert resumed is not None and whole.stats.get("ordering_checks", 0) >= 2  # the schedule compared again


@pytest.mark.parametrize("made_before_load", [False, True])
def test_a_siblings_state_is_kept_with_its_solvers(made_before_load: bool) -> None:
    """The Newton loop factorises the system without its held DOFs on a sibling solver (HeldReduction), whose
    orderings depend on its own history: the main solver's state carries it, so a resumed run's sibling (made
    before or after the checkpoint is loaded) chooses as the uninterrupted run's does."""
    patterns = [make_matrix(nx=6, seed=0, contacts=c) for c in (0, 4, 8, 12, 16, 20, 24, 28)]
    whole = _cholmod_solver(3)
    whole_sibling = cast("CholmodSolver", whole.sibling())
    b = np.random.default_rng(5).standard_normal(patterns[0].shape[0])
    for A in patterns[:3]:
        whole.factorize(patterns[0])
        whole_sibling.factorize(A)
    state = whole.state()
    assert "sibling0__schedule" in state and "sibling0__perm" in state
    resumed = _cholmod_solver(3)
    early = resumed.sibling() if made_before_load else None
    resumed.load_state(state)
    sibling = cast("CholmodSolver", early if early is not None else resumed.sibling())
    for A in patterns[2:]:
        whole_sibling.factorize(A)
        sibling.factorize(A)
        assert np.array_equal(_ordering_of(sibling), _ordering_of(whole_sibling))
        assert sibling.state()["schedule"].tolist() == whole_sibling.state()["schedule"].tolist()
        assert np.allclose(sibling.solve(b), whole_sibling.solve(b), rtol=1e-10, atol=1e-12)
    assert resumed.state()["sibling0__schedule"].tolist() == whole.state()["sibling0__schedule"].tolist()


def test_reset_stats_keeps_siblings_counting_into_the_same_statistics() -> None:
    solver = _cholmod_solver(3)
    sibling = solver.sibling()
    solver.reset_stats()
    sibling.factorize(make_matrix(nx=4, seed=0))
    assert solver.stats["factorizations"] == 1


def test_cholmod_state_of_another_pattern_is_not_taken() -> None:
    solver = _cholmod_solver(3)
    solver.factorize(make_matrix(nx=6, seed=0, contacts=8))
    other = _cholmod_solver(3)
    other.load_state(solver.state())
    A = make_matrix(nx=6, seed=0, contacts=20)  # not the pattern the state was analysed on: ordered afresh
    other.factorize(A)
    fresh = _cholmod_solver(3)
    fresh.load_state({"schedule": solver.state()["schedule"]})
    fresh.factorize(A)
    assert np.array_equal(_ordering_of(other), _ordering_of(fresh))


@pytest.mark.parametrize(
    "damage",
    [
        {"schedule": np.array(["a", "b", "c"])},
        {"schedule": np.full(3, np.nan)},
        {"schedule": np.zeros((2, 2), np.int64)},
        {"perm": np.full(3, 2**62, dtype=np.int64)},
        {"perm": np.zeros(0, np.int64)},
        {"fingerprint": np.zeros(4, np.complex128)},
    ],
)
def test_cholmod_state_damaged_in_a_checkpoint_is_ignored(damage: dict) -> None:
    A = make_matrix(nx=6, seed=0, contacts=8)
    solver = _cholmod_solver(3)
    solver.factorize(A)
    state = {**solver.state(), **damage}
    resumed = _cholmod_solver(3)
    resumed.load_state(state)  # no exception: the solver chooses afresh where the state is not usable
    resumed.factorize(A)
    b = np.ones(A.shape[0])
    assert rel_residual(A, resumed.solve(b), b) < 1e-10
    assert np.array_equal(np.sort(_ordering_of(resumed)), np.arange(A.shape[0]))
