"""CG preconditioned by a folded majorant reaches the exact Newton direction."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

# pytest puts this test directory on sys.path; mypy checks tests/ by file and cannot resolve the sibling module
from test_contact_pattern import _chain_problem, _pair_hessian, _reference  # type: ignore[import-not-found]

from idp.solver.contact_pattern import GrowingBlockPattern
from idp.solver.pcg import pcg_from_majorant


@pytest.mark.parametrize("seed", range(3))
def test_pcg_from_the_folded_factor_gives_the_exact_direction(seed):
    rng, dmap, asm, blocks, diag = _chain_problem()
    rng = np.random.default_rng(seed)
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24, scale=1e3) + _pair_hessian(rng, [5, 19], 24, scale=1e2)
    M = pattern.assemble(asm.assemble_data([blocks], [1.0], diag), C, dmap.global_to_free)
    assert pattern.last_folded
    K = pattern.fold_correction
    H = _reference(asm, blocks, diag, C, dmap)
    assert np.allclose((M + K).toarray(), H)
    lu = spla.splu(sp.csc_matrix(M))
    b = rng.standard_normal(M.shape[0])
    x0 = lu.solve(b)
    x, its, ok = pcg_from_majorant(lambda v: M @ v + K @ v, lu.solve, b, x0, 1e-10, 100)
    exact = np.linalg.solve(H, b)
    assert ok and 0 < its <= 2 * K.nnz
    assert np.allclose(x, exact, rtol=1e-7, atol=1e-9 * np.abs(exact).max())
    assert np.abs(x0 - exact).max() > 1e-3 * np.abs(exact).max()  # folding did change the direction
    # every iterate is a descent direction of the quadratic model ½xᵀHx − bᵀx (here: from x0 on)

    def q(y):
        return 0.5 * y @ H @ y - b @ y

    x1, _, _ = pcg_from_majorant(lambda v: M @ v + K @ v, lu.solve, b, x0, 0.0, 1)
    assert q(x1) <= q(x0) < 0


def test_pcg_reports_a_hit_cap_and_an_indefinite_matrix():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((30, 30))
    H = A @ A.T + np.eye(30)
    b = rng.standard_normal(30)

    def ident(v):
        return v.copy()

    _, its, ok = pcg_from_majorant(lambda v: H @ v, ident, b, b, 1e-12, 3)
    assert not ok and its == 3
    _, its, ok = pcg_from_majorant(lambda v: -v, ident, b, b, 1e-12, 10)
    assert not ok


@pytest.mark.parametrize("backend", ["scipy", "auto"])
@pytest.mark.parametrize("cap", [100, 0])
def test_newton_exact_direction_after_a_fold(backend, cap):
    """StepSolver._exact_direction returns −H⁻¹g of the unfolded matrix: by CG from the folded factor, or
    (cap 0) by growing the pattern and factorising the exact matrix."""
    from types import SimpleNamespace

    from idp.solver.linear import make_linear_solver
    from idp.solver.newton import NewtonResult, NewtonSettings, StepSolver

    rng, dmap, asm, blocks, diag = _chain_problem()
    pattern = GrowingBlockPattern(asm.layout, fold_limit=64)
    C = _pair_hessian(rng, [2, 15, 16, 17], 24, scale=1e3)
    M = pattern.assemble(asm.assemble_data([blocks], [1.0], diag), C, dmap.global_to_free)
    assert pattern.last_folded
    solver = StepSolver(
        SimpleNamespace(contact_pattern=pattern, terms=[]),
        NewtonSettings(pcg_rtol=1e-10, pcg_max_iterations=cap),
        make_linear_solver(backend),
    )
    res = NewtonResult()
    g = rng.standard_normal(M.shape[0])
    p_folded = solver._direction(M, g, res)
    p = solver._exact_direction(M, g, p_folded, res)
    exact = -np.linalg.solve(_reference(asm, blocks, diag, C, dmap), g)
    assert np.allclose(p, exact, rtol=1e-6, atol=1e-8 * np.abs(exact).max())
    if cap:
        assert res.pcg_iterations > 0 and res.exact_refactorizations == 0 and pattern.growths == 0
    else:
        assert res.exact_refactorizations == 1 and pattern.growths == 1
