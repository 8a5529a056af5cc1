"""CHOLMOD's BLAS routed to scipy's threaded OpenBLAS (idp.solver.cholmod_blas): the table entries it rewrites are
CHOLMOD's own, solves agree with scipy's, the pool size is restored, and it can be turned off."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

pytest.importorskip("cvxopt", reason="cvxopt not importable: CHOLMOD backend (pip install idp[cholmod]) not tested")

from idp.solver import cholmod_blas
from idp.solver.cholmod_cvxopt import CholmodSolver


def _routed() -> bool:
    CholmodSolver(3)  # a solver routes once per process
    return cholmod_blas._set_threads is not None


def test_every_routine_has_a_table_entry_in_cholmod():
    import cvxopt.cholmod  # noqa: F401

    found = cholmod_blas._load_bias("libcholmod")
    if found is None:
        pytest.skip("libcholmod not loaded as a separate shared object")
    slots = cholmod_blas._got_slots(found[0], cholmod_blas.ROUTINES)
    assert all(slots[name] for name in cholmod_blas.ROUTINES), slots


def test_a_file_that_is_not_elf_is_refused(tmp_path):
    f = tmp_path / "x.so"
    f.write_bytes(b"not an ELF file at all" * 4)
    with pytest.raises(ValueError, match="ELF64"):
        cholmod_blas._got_slots(str(f), ("dgemm_",))


@pytest.mark.parametrize("threaded", [False, True])
def test_routed_solves_agree_with_scipy_and_the_pool_size_is_restored(monkeypatch, threaded):
    from idp.solver import cholmod_cvxopt

    monkeypatch.setattr(cholmod_cvxopt, "THREADED_MIN_DOFS", 0 if threaded else 10**9)
    monkeypatch.setattr(cholmod_blas, "_threads", 2)
    if not _routed():
        pytest.skip(f"not routed here: {cholmod_blas.STATUS}")
    assert "scipy's OpenBLAS" in cholmod_blas.STATUS
    # a 3D grid Laplacian plus a shift: supernodes large enough for dgemm / dsyrk / dtrsm / dpotrf
    n1 = 14
    L1 = sp.diags([-np.ones(n1 - 1), 2 * np.ones(n1), -np.ones(n1 - 1)], [-1, 0, 1])
    I1 = sp.identity(n1)
    A = (sp.kron(sp.kron(L1, I1), I1) + sp.kron(sp.kron(I1, L1), I1) + sp.kron(sp.kron(I1, I1), L1)).tocsr()
    A = (A + 0.1 * sp.identity(A.shape[0])).tocsr()
    A = sp.kron(A, sp.identity(3)).tocsr()  # 3 DOFs per node, as the solver expects
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    before = cholmod_blas._get_threads()
    s = CholmodSolver(3)
    s.factorize(A)
    assert s._threaded == threaded
    x = s.solve(b)
    assert cholmod_blas._get_threads() == before
    expected = spla.spsolve(A.tocsc(), b)
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_the_table_entries_hold_scipys_routines_once_routed():
    if not _routed():
        pytest.skip(f"not routed here: {cholmod_blas.STATUS}")
    import glob
    from pathlib import Path

    import scipy

    path, bias = cholmod_blas._load_bias("libcholmod")
    lib = ctypes.CDLL(glob.glob(str(Path(scipy.__file__).parent.parent / "scipy.libs" / "libscipy_openblas*.so"))[0])
    for name, offsets in cholmod_blas._got_slots(path, cholmod_blas.ROUTINES).items():
        target = cholmod_blas._address(lib, "scipy_" + name)
        assert all(ctypes.c_void_p.from_address(bias + off).value == target for off in offsets), name


def test_routing_can_be_turned_off():
    code = (
        "from idp.solver.cholmod_cvxopt import CholmodSolver; from idp.solver import cholmod_blas; "
        "CholmodSolver(3); print(cholmod_blas.STATUS)"
    )
    env = dict(os.environ, IDP_CHOLMOD_BLAS="bundled")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "off (IDP_CHOLMOD_BLAS)"
