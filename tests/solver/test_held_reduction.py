"""Tests of idp.solver.held_reduction: factorising only the DOFs not held gives the zeroed full system's solution."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from test_linear import BACKENDS, make_matrix, new_solver  # type: ignore[import-not-found]

from idp.errors import SolverError
from idp.solver.held_reduction import HeldReduction, keeps_vertex_groups
from idp.solver.linear import NotPositiveDefinite, ScipySolver


def zeroed(A: sp.csr_matrix, held: np.ndarray) -> sp.csr_matrix:
    """A with the rows and columns of held DOFs zeroed but for the diagonal, the pattern kept (as the Newton loop's
    ``_hold`` does)."""
    H = A.copy()
    rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
    H.data[(held[rows] | held[H.indices]) & (rows != H.indices)] = 0.0
    return H


def held_vertices(nv: int, d: int, share: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.random(nv) < share, d)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("share", [0.1, 0.5, 0.9])
def test_reduced_solution_equals_the_zeroed_full_systems(backend: str, share: float) -> None:
    A = make_matrix(8, 3, seed=2, contacts=30)
    held = held_vertices(A.shape[0] // 3, 3, share, seed=3)
    H = zeroed(A, held)
    full = new_solver(backend)
    full.factorize(H)
    red = HeldReduction(full.sibling())
    red.factorize(H, held)
    rng = np.random.default_rng(4)
    for b in (rng.standard_normal(H.shape[0]), rng.standard_normal((H.shape[0], 3))):
        x_full, x_red = full.solve(b), red.solve(b)
        # both solve the same SPD system; the condition number of these grid matrices is O(10^3)
        assert np.allclose(x_red, x_full, rtol=1e-9, atol=1e-11 * np.abs(x_full).max())
        assert np.linalg.norm(H @ x_red - b) <= 1e-10 * np.linalg.norm(b)
    # held rows: b / diagonal exactly (a gradient zeroed there gives a direction exactly zero there)
    b = rng.standard_normal(H.shape[0])
    b[held] = 0.0
    assert np.all(red.solve(b)[held] == 0.0)


def test_the_reduced_pattern_is_analysed_once_per_held_set() -> None:
    A = make_matrix(8, 3, seed=5)
    held = held_vertices(A.shape[0] // 3, 3, 0.4, seed=6)
    backend = ScipySolver(dofs_per_node=3)
    red = HeldReduction(backend)
    for k in range(3):  # new values, same pattern and held set: no new index map, one ordering
        H = zeroed(A * (1.0 + k), held)
        red.factorize(H, held)
    assert backend.stats["factorizations"] == 3
    assert backend.stats["symbolic_reuses"] >= 2
    other = held_vertices(A.shape[0] // 3, 3, 0.4, seed=7)
    red.factorize(zeroed(A, other), other)
    b = np.ones(A.shape[0])
    x = red.solve(b)
    assert np.linalg.norm(zeroed(A, other) @ x - b) <= 1e-10 * np.linalg.norm(b)


def test_sibling_shares_statistics_but_not_pattern_work() -> None:
    full = ScipySolver(dofs_per_node=3)
    sib = full.sibling()
    assert sib.stats is full.stats and sib is not full and sib.dofs_per_node == 3
    A = make_matrix(6, 3, seed=8)
    held = held_vertices(A.shape[0] // 3, 3, 0.5, seed=9)
    full.factorize(A)
    HeldReduction(sib).factorize(zeroed(A, held), held)
    assert full.stats["factorizations"] == 2
    b = np.ones(A.shape[0])
    assert np.linalg.norm(A @ full.solve(b) - b) <= 1e-10 * np.linalg.norm(b)  # the full factor is still there


def test_whole_vertex_groups() -> None:
    assert keeps_vertex_groups(np.array([True, True, True, False, False, False]), 3)
    assert not keeps_vertex_groups(np.array([True, False, False, False, False, False]), 3)
    assert not keeps_vertex_groups(np.array([True, True]), 3)
    assert keeps_vertex_groups(np.array([True, False]), 1)


def test_a_non_positive_held_diagonal_is_not_positive_definite() -> None:
    A = make_matrix(4, 3, seed=10)
    held = held_vertices(A.shape[0] // 3, 3, 0.5, seed=11)
    H = zeroed(A, held)
    rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
    first = np.flatnonzero(held)[0]
    H.data[(rows == first) & (H.indices == first)] = -1.0
    red = HeldReduction(ScipySolver(dofs_per_node=3))
    red.factorize(zeroed(A, held), held)
    with pytest.raises(NotPositiveDefinite):
        red.factorize(H, held)
    with pytest.raises(SolverError):  # no stale factor answers after a failed factorisation
        red.solve(np.ones(H.shape[0]))
