"""A folded matrix's direction is kept only while the fold barely changes it (StepSolver._undistorted).

Folding a missing coupling B onto the diagonal makes a majorant that is stiffer than the Hessian wherever the two
coupled vertices must move together; where that stiffening is large along the direction, the direction is not
Newton's (petals sagging onto petals stalled for tens of iterations), and the exact matrix is factorised instead."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from solver.test_contact_pattern import DIM, _chain_problem, _pair_hessian, _reference

from idp.solver.contact_pattern import GrowingBlockPattern
from idp.solver.linear import make_linear_solver
from idp.solver.newton import NewtonResult, NewtonSettings, StepSolver


class _PatternOnly:
    """The one part of a system that StepSolver._undistorted reads."""

    def __init__(self, pattern):
        self.contact_pattern = pattern
        self.terms: list = []


def _solver(pattern) -> StepSolver:
    return StepSolver(_PatternOnly(pattern), NewtonSettings(), make_linear_solver("scipy", DIM))


def _point_pair_hessian(v0: int, v1: int, normal: np.ndarray, nv: int, scale: float) -> sp.csc_matrix:
    """A point-point barrier's Hessian along ``normal``: stiff against the two points closing, free for them moving
    together (CSC on all vertices' DOFs)."""
    nn = scale * np.outer(normal, normal)
    local = np.block([[nn, -nn], [-nn, nn]])
    idx = (np.array([v0, v1])[:, None] * DIM + np.arange(DIM)).ravel()
    r, c = np.meshgrid(idx, idx, indexing="ij")
    return sp.csc_matrix((local.ravel(), (r.ravel(), c.ravel())), shape=(nv * DIM, nv * DIM))


def _folded(scale: float):
    """A soft chain, two of whose far-apart vertices (2 and 15) touch: their barrier coupling is folded, and the
    gradient pulls both along the contact normal (gravity on two sagging petals). Returns (pattern, folded
    matrix, exact matrix, gradient)."""
    rng, dmap, asm, blocks, diag = _chain_problem()
    soft = 1e-2
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    data = asm.assemble_data([soft * blocks], [1.0], soft * diag)
    normal = np.array([0.0, 1.0, 0.0])
    C = _point_pair_hessian(2, 15, normal, 24, scale)
    M = pattern.assemble(data, C, dmap.global_to_free)
    assert pattern.last_folded
    exact = _reference(asm, soft * blocks, soft * diag, C, dmap)
    g = 1e-3 * rng.standard_normal(dmap.num_free)
    for v in (2, 15):
        g[dmap.global_to_free[v * DIM : v * DIM + DIM]] += normal
    return pattern, M, exact, g


def test_a_fold_that_barely_changes_the_direction_is_kept():
    pattern, M, _, g = _folded(scale=1e-6)
    solver = _solver(pattern)
    p = -solver._factorize(M)(g)
    res = NewtonResult()
    assert solver._undistorted(p, g, res) is p
    assert res.distorted_folds == 0 and pattern.growths == 0 and pattern.last_folded


@pytest.mark.parametrize("scale", [1e2, 1e4])
def test_a_stiffening_fold_is_replaced_by_the_exact_direction(scale):
    pattern, M, exact, g = _folded(scale=scale)
    solver = _solver(pattern)
    p = -solver._factorize(M)(g)
    res = NewtonResult()
    q = solver._undistorted(p, g, res)
    newton = -np.linalg.solve(exact, g)
    assert np.linalg.norm(p - newton) > 0.1 * np.linalg.norm(newton)  # the folded direction is far from Newton's
    assert np.allclose(q, newton, rtol=1e-8, atol=1e-10 * np.abs(newton).max())
    assert res.distorted_folds == 1 and pattern.growths == 1 and not pattern.last_folded


def test_no_fold_no_check():
    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=0)  # never folds: grows
    data = asm.assemble_data([blocks], [1.0], diag)
    M = pattern.assemble(data, _pair_hessian(rng, [2, 15, 16, 17], 24, scale=1e4), dmap.global_to_free)
    assert not pattern.last_folded
    g = rng.standard_normal(dmap.num_free)
    solver = _solver(pattern)
    p = -solver._factorize(M)(g)
    res = NewtonResult()
    assert solver._undistorted(p, g, res) is p and res.distorted_folds == 0


class _UnitPenalty:
    """A step constraint whose penalty gives each tool a unit stiffness (the bordered system's D block)."""

    def __init__(self, size: int):
        self.size = size

    def penalty_hessian_diagonal(self) -> np.ndarray:
        return np.ones(self.size)


def test_the_fold_check_applies_while_kinematic_tools_move():
    """The bordered solve of a kinematic tool (StepSolver._direction_with_tools) takes the body's direction from the
    exact matrix too when the fold distorts it."""
    pattern, M, exact, g = _folded(scale=1e4)
    system = _PatternOnly(pattern)
    system.dim = DIM
    solver = StepSolver(system, NewtonSettings(), make_linear_solver("scipy", DIM))
    nd = 24 * DIM
    solver._constraint = _UnitPenalty(nd)
    tool = (np.array([0]), np.array([[0.0, 1.0, 0.0]]))  # vertex 0 is pinned: a tool's vertex, no free DOF
    res = NewtonResult()
    p, q = solver._direction_with_tools(M, g, np.zeros(nd), None, [tool], res)
    newton = -np.linalg.solve(exact, g)
    assert res.distorted_folds == 1 and pattern.growths == 1
    assert np.allclose(p, newton, rtol=1e-8, atol=1e-10 * np.abs(newton).max())
    assert q.shape == (1,)


def _second_contact(pattern, dmap, asm, blocks, diag, soft: float = 1e-2):
    """Assemble the same chain again with a new contact (vertices 5 and 20, outside the pattern so far)."""
    data = asm.assemble_data([soft * blocks], [1.0], soft * diag)
    C = _point_pair_hessian(5, 20, np.array([1.0, 0.0, 0.0]), 24, 1e4)
    return pattern.assemble(data, C, dmap.global_to_free)


@pytest.mark.parametrize("stop_after", [0, 1, 2])
def test_distorted_folds_in_a_row_stop_the_step_folding(stop_after):
    """After ``fold_stop_after`` folds in a row distorted their directions, the rest of the step grows the pattern
    for new couplings (no folded factorisation thrown away); 0: it always folds."""
    pattern, M, _, g = _folded(scale=1e4)
    solver = StepSolver(
        _PatternOnly(pattern),
        NewtonSettings(fold_stop_after=stop_after, fold_stop_min_dofs=g.size),
        make_linear_solver("scipy", DIM),
    )
    solver._undistorted(-solver._factorize(M)(g), g, NewtonResult())
    assert pattern.folding is (stop_after != 1)
    _, dmap, asm, blocks, diag = _chain_problem()
    folds, growths = pattern.folds, pattern.growths
    M2 = _second_contact(pattern, dmap, asm, blocks, diag)
    if stop_after == 1:
        assert not pattern.last_folded and (pattern.folds, pattern.growths) == (folds, growths + 1)
        return
    assert pattern.last_folded and (pattern.folds, pattern.growths) == (folds + 1, growths)
    g2 = g.copy()
    for v in (5, 20):
        g2[dmap.global_to_free[v * DIM : v * DIM + DIM]] += np.array([1.0, 0.0, 0.0])
    solver._undistorted(-solver._factorize(M2)(g2), g2, NewtonResult())
    assert pattern.folding is (stop_after == 0)


def test_a_kept_fold_ends_the_run_of_distorted_ones():
    pattern, M, _, g = _folded(scale=1e-6)
    solver = _solver(pattern)
    solver._distorted_run = 1
    assert solver._undistorted(-solver._factorize(M)(g), g, NewtonResult()) is not None
    assert solver._distorted_run == 0 and pattern.folding


def test_small_systems_keep_folding():
    """Below ``fold_stop_min_dofs`` free DOFs (an analysis costing more than a factorisation) folds go on."""
    pattern, M, _, g = _folded(scale=1e4)
    solver = StepSolver(
        _PatternOnly(pattern),
        NewtonSettings(fold_stop_after=1, fold_stop_min_dofs=g.size + 1),
        make_linear_solver("scipy", DIM),
    )
    solver._undistorted(-solver._factorize(M)(g), g, NewtonResult())
    assert solver._distorted_run == 1 and pattern.folding


def test_each_step_tries_folding_again():
    """StepSolver.solve resets the pattern's folding before its first assembly."""
    pattern, *_ = _folded(scale=1e4)
    pattern.folding = False

    class _Stop(Exception):
        pass

    solver = StepSolver(_PatternOnly(pattern), NewtonSettings(), make_linear_solver("scipy", DIM))
    solver.system.contact = None
    solver.system.step_constraint = None

    def stop(*args, **kwargs):
        raise _Stop

    solver._solve = stop
    with pytest.raises(_Stop):
        solver.solve(np.zeros((24, DIM)))
    assert pattern.folding
