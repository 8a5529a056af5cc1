"""Memory guard: size parsing, available memory (meminfo, cgroup v1/v2), the estimate and the check."""

import logging

import numpy as np
import pytest
import scipy.sparse as sp

from idp.errors import ResourceError, SolverError
from idp.solver.grid_matrices import grid_block_pattern
from idp.solver.linear import ScipySolver, available_solvers, have_pymetis, make_linear_solver
from idp.solver.memory import (
    MemoryGuard,
    available_memory,
    format_bytes,
    parse_memory_size,
    step_overhead_bytes,
)
from idp.solver.symbolic import symbolic_counts


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("4G", 4 << 30),
        ("4g", 4 << 30),
        ("512M", 512 << 20),
        ("1.5T", 3 << 39),
        ("4GiB", 4 << 30),
        ("4GB", 4 << 30),
        (" 100 K ", 100 << 10),
        ("1000", 1000),
        (1000, 1000),
        (2.5e9, 2_500_000_000),
    ],
)
def test_parse_memory_size(text, expected):
    assert parse_memory_size(text) == expected


@pytest.mark.parametrize("bad", ["", "G", "4X", "-1G", "0", "0M", "four", "1e3G", "nan", True, None, [4], -5, 0.0])
def test_parse_memory_size_rejects(bad):
    with pytest.raises(ValueError, match=r"memory size|size such as"):
        parse_memory_size(bad)


def test_format_bytes():
    assert format_bytes(512) == "512 B"
    assert format_bytes(1536) == "1.5 KiB"
    assert format_bytes(37.2 * 2**30) == "37.2 GiB"


def _meminfo(tmp_path, kb: int):
    p = tmp_path / "meminfo"
    p.write_text(f"MemTotal:       99999999 kB\nMemFree:  1 kB\nMemAvailable:   {kb} kB\n")
    return p


def test_available_memory_from_meminfo_only(tmp_path):
    got = available_memory(_meminfo(tmp_path, 2048), tmp_path / "no-cgroup", tmp_path / "no-sys")
    assert got == (2048 * 1024, "MemAvailable")
    assert available_memory(tmp_path / "none", tmp_path / "none", tmp_path / "none") is None


def test_available_memory_cgroup_v2_caps_meminfo(tmp_path):
    sysfs = tmp_path / "cg"
    leaf = sysfs / "user.slice" / "job"
    leaf.mkdir(parents=True)
    (sysfs / "cgroup.controllers").write_text("memory cpu\n")
    (leaf / "memory.max").write_text(str(1 << 30))
    (leaf / "memory.current").write_text(str(700 << 20))
    (leaf / "memory.stat").write_text(f"anon 1\ninactive_file {100 << 20}\nactive_file 5\n")
    (sysfs / "user.slice" / "memory.max").write_text("max\n")
    proc = tmp_path / "cgroup"
    proc.write_text("0::/user.slice/job\n")
    got = available_memory(_meminfo(tmp_path, 8 << 20), proc, sysfs)
    assert got == ((1 << 30) - (600 << 20), "cgroup memory limit")  # limit - (usage - inactive page cache)
    # a looser cgroup than MemAvailable leaves MemAvailable in charge
    (leaf / "memory.max").write_text(str(64 << 30))
    assert available_memory(_meminfo(tmp_path, 8 << 20), proc, sysfs) == (8 << 30, "MemAvailable")


def test_available_memory_cgroup_v1_tightest_level_and_container_root(tmp_path):
    sysfs = tmp_path / "cg"
    mem = sysfs / "memory"
    (mem / "a" / "b").mkdir(parents=True)
    (mem / "memory.limit_in_bytes").write_text("9223372036854771712\n")  # unlimited at the root
    (mem / "a" / "memory.limit_in_bytes").write_text(str(2 << 30))
    (mem / "a" / "memory.usage_in_bytes").write_text(str(1 << 30))
    (mem / "a" / "b" / "memory.limit_in_bytes").write_text(str(4 << 30))
    (mem / "a" / "b" / "memory.usage_in_bytes").write_text(str(1 << 30))
    proc = tmp_path / "cgroup"
    proc.write_text("5:cpu,cpuacct:/a/b\n4:memory:/a/b\n")
    assert available_memory(_meminfo(tmp_path, 8 << 20), proc, sysfs) == (1 << 30, "cgroup memory limit")
    # inside a container the process's cgroup path is not under the mount: its root holds the limit
    proc.write_text("4:memory:/elsewhere/xyz\n")
    (mem / "memory.limit_in_bytes").write_text(str(3 << 30))
    (mem / "memory.usage_in_bytes").write_text(str(1 << 30))
    assert available_memory(_meminfo(tmp_path, 8 << 20), proc, sysfs) == (2 << 30, "cgroup memory limit")


def test_available_memory_on_this_machine_is_sane():
    got = available_memory()
    if got is None:
        pytest.skip("no /proc/meminfo here")
    assert got[0] > 0 and got[1] in ("MemAvailable", "cgroup memory limit")


def _matrix(nx: int = 6) -> sp.csr_matrix:
    A = grid_block_pattern(nx)
    return (A + sp.eye(A.shape[0]) * 100.0).tocsr()


@pytest.mark.parametrize("backend", available_solvers())
def test_estimate_is_a_sane_multiple_of_the_exact_factor(backend):
    """The factor's bytes are a small multiple of 8 B per nonzero of L, the total a small multiple of the factor."""
    if not have_pymetis():
        pytest.skip("needs pymetis (the guard counts with the solver's ordering)")
    A = _matrix(8)
    n = A.shape[0]
    solver = make_linear_solver(backend, dofs_per_node=3)
    guard = solver.memory_guard = MemoryGuard(available=lambda: (1 << 50, "MemAvailable"))
    solver.factorize(A)
    est = guard.last
    assert est is not None and est.backend == backend
    exact = symbolic_counts(A.indptr, A.indices, n, np.arange(n)).nnz_factor  # natural order: more fill
    assert est.counts.n == n and est.counts.nnz_matrix == A.nnz
    assert A.nnz < est.counts.nnz_factor < exact
    assert 8 * est.counts.nnz_factor <= est.factor_bytes <= 30 * est.counts.nnz_factor
    assert est.hessian_bytes >= 12 * A.nnz
    assert est.factor_bytes < est.total < 3 * (est.factor_bytes + est.workspace_bytes + est.hessian_bytes)
    assert guard.checks == 1 and est.to_dict()["total_bytes"] == est.total


@pytest.mark.parametrize("backend", available_solvers())
def test_guard_stops_before_the_first_factorisation(backend):
    if not have_pymetis():
        pytest.skip("needs pymetis (the guard counts with the solver's ordering)")
    solver = make_linear_solver(backend, dofs_per_node=3)
    solver.memory_guard = MemoryGuard(1 << 20, available=lambda: (1 << 50, "MemAvailable"))
    with pytest.raises(ResourceError, match=r"not enough memory: the step needs about .* for 648 DOFs") as info:
        solver.factorize(_matrix(6))
    assert isinstance(info.value, SolverError)
    msg = str(info.value)
    assert "but the limit is 1 MiB (solver.max_memory)" in msg and "coarser mesh" in msg and "--max-memory" in msg
    assert solver.stats["factorizations"] == 0
    if backend == "cholmod":  # not even CHOLMOD's symbolic analysis ran
        assert solver.stats["symbolic_analyses"] == 0


def test_guard_names_the_system_limit():
    solver = ScipySolver(dofs_per_node=3, use_metis=have_pymetis())
    if not solver.use_metis:
        pytest.skip("needs pymetis")
    solver.memory_guard = MemoryGuard(64 << 30, available=lambda: (1000, "cgroup memory limit"))
    with pytest.raises(ResourceError, match=r"but 1000 B are available \(limit: cgroup memory limit\)"):
        solver.factorize(_matrix(4))


def test_guard_rechecks_only_when_the_estimate_grows(caplog):
    if not have_pymetis():
        pytest.skip("needs pymetis")
    calls = []

    def avail():
        calls.append(1)
        return (1 << 50, "MemAvailable")

    solver = ScipySolver(dofs_per_node=3)
    guard = solver.memory_guard = MemoryGuard(available=avail)
    A = _matrix(5)
    solver.factorize(A)
    first = guard.last
    assert len(calls) == 1 and first is not None
    B = A.copy()
    B.data[:] = 2.0 * B.data + 1.0
    B = (B + sp.diags(np.ones(B.shape[0]))).tocsr()
    solver.factorize(B)  # same pattern: no analysis, no check
    assert len(calls) == 1
    C = (A + sp.csr_matrix(([1e-3, 1e-3], ([0, A.shape[0] - 1], [A.shape[0] - 1, 0])), shape=A.shape)).tocsr()
    solver.factorize(C)  # a new pattern, a little larger: counted, not checked again
    assert len(calls) == 1 and guard.last is not first and guard.peak is guard.last
    D = (A + sp.random(A.shape[0], A.shape[0], density=0.2, random_state=0)).tocsr()
    D = (D + D.T + sp.eye(D.shape[0]) * 1e3).tocsr()
    solver.factorize(D)  # much larger: checked again
    assert len(calls) == 2 and guard.checks == 2


def test_guard_skips_without_ordering_or_information(caplog):
    solver = ScipySolver(dofs_per_node=3, use_metis=False)
    guard = solver.memory_guard = MemoryGuard(1, available=lambda: None)
    with caplog.at_level(logging.DEBUG, logger="idp"):
        solver.factorize(_matrix(3))  # SuperLU orders inside splu: nothing to count
    assert guard.last is None and "chooses its ordering" in caplog.text
    if have_pymetis():
        solver = ScipySolver(dofs_per_node=3, use_metis=True)
        guard = solver.memory_guard = MemoryGuard(None, available=lambda: None)
        with caplog.at_level(logging.DEBUG, logger="idp"):
            solver.factorize(_matrix(3))
        assert guard.last is not None and guard.checks == 0 and "no memory information" in caplog.text


def test_step_overhead_bytes():
    assert step_overhead_bytes(0) == 0
    assert step_overhead_bytes(300, 10) == 40 * 8 * 300 + 10 * 1024
