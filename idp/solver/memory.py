"""Memory guard: estimate a step's peak memory from the symbolic analysis and stop before the OS kills the run.

Before the first numeric factorisation of a run the linear solver hands the guard its sparsity pattern and the
fill-reducing ordering it is about to use; the guard counts the Cholesky factor exactly
(:func:`idp.solver.symbolic.symbolic_counts`, almost linear in nnz(A): 11 ms at 24K DOF, 48 ms at 118K DOF
with 5M entries, where METIS took 53 and 356 ms), asks the backend
what that factor costs in bytes (:meth:`idp.solver.linear.LinearSolver.memory_estimate`) and compares the step's
estimated peak with the memory available. Too much: :class:`~idp.errors.ResourceError`, naming what is needed and
what to change, before the factorisation allocates anything. Later pattern changes (contacts appearing) are
counted too (the count is cheap next to the ordering they come with) and checked again when the estimate has grown
by more than ``regrowth`` (25 %) over the largest one checked, so a large new contact pattern is caught without
reading the limits on every change.

The step's peak (:class:`MemoryEstimate`) is

* the factor as the backend stores it plus its factorisation workspace (the backends' ``factor_bytes``:
  CHOLMOD supernodal ≈ 8.4 B per entry of the supernodes' dense blocks + the largest update block + a permuted
  copy of A; SuperLU ≈ 8 B per supernodal L entry + 12 B per U entry);
* the Hessian and the copies and index maps kept of its pattern (assembly, the solver's lower triangle, the
  pattern cache): a fixed number of bytes per stored entry, per backend;
* dense vectors and contact sets: 40 vectors of the scene's DOFs plus 1 KiB per collision-surface primitive
  (:func:`step_overhead_bytes`).

The interpreter and libraries (≈ 0.3–0.5 GB) are not part of the estimate: they are already resident when it is
made, so the memory *available* then is what the step may still take.

Measured (``bench/bench_memory.py``, 2-core x86-64 VM (Intel, 2026-11-28); one step of a ball of tets (3D) or a
triangulated disk (2D) growing inside a box; the run's peak RSS growth over the RSS after building the scene, VmHWM
reset through /proc/self/clear_refs; estimate: the largest of the run, with the 15 % margin)::

    dim solver   DOFs     nnz(A)     nnz(L)      measured  estimate  estimate/measured
    3D  cholmod   14,739    602,649   4,857,663     85 MB    117 MB   1.38
    3D  cholmod   46,875  1,977,057  27,743,442    391 MB    502 MB   1.28
    3D  cholmod  107,811  4,619,817  87,566,742  1,147 MB  1,433 MB   1.25
    3D  scipy     14,739    602,649   4,857,663    129 MB    167 MB   1.29   (3 Newton iterations)
    3D  scipy     36,501  1,530,747  17,601,150    420 MB    540 MB   1.29   (3 Newton iterations)
    2D  cholmod  206,082  2,874,884  16,490,175    321 MB    452 MB   1.41   (4 Newton iterations)
    2D  cholmod  462,722  6,462,724  41,493,375    742 MB  1,063 MB   1.43   (4 Newton iterations)

    bench/bench_memory.py --dim 3 --solver cholmod --sizes 8 12 16
    bench/bench_memory.py --dim 3 --solver scipy --sizes 8 11 --iterations 3
    bench/bench_memory.py --dim 2 --solver cholmod --sizes 160 240 --iterations 4

The step itself got smaller that day (CHOLMOD given the upper triangle: one copy of it fewer during a factorisation;
the contact blocks added a range at a time; the elastic values no longer copied; the AMD VM's figures before were
105 / 455 / 1,227 MB for the three 3D CHOLMOD rows): the model counts the two copies of the stored triangle the
factorisation holds and 32 B per Hessian entry (the CSR matrix 12, the backend's copy of its triangle 8, the
layouts' index maps), and stays above every measurement. The earlier calibration (AMD VM, 48 B per entry and one
copy of the triangle in the workspace) was 1.14–1.20× on the 3D CHOLMOD rows.

Available memory (:func:`available_memory`) is ``MemAvailable`` of /proc/meminfo, capped by the process's cgroup:
v2 ``memory.max − memory.current`` (less reclaimable ``inactive_file`` page cache), v1
``memory.limit_in_bytes − memory.usage_in_bytes`` (same), taking the tightest level from the process's cgroup up
to the root of the mount. A user limit (``solver.max_memory``, ``idp run --max-memory``) caps it further. Where
nothing is known (no /proc) and no user limit is given, the check is skipped with a debug log.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from idp.errors import ResourceError
from idp.solver.symbolic import SymbolicCounts, symbolic_counts

if TYPE_CHECKING:
    from idp.solver.linear import LinearSolver

__all__ = [
    "MemoryEstimate",
    "MemoryGuard",
    "available_memory",
    "format_bytes",
    "parse_memory_size",
    "step_overhead_bytes",
]

log = logging.getLogger("idp")

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_SIZE = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*([KMGT]?)(?:I?B)?\s*$", re.IGNORECASE)


def parse_memory_size(value: Any) -> int:
    """Bytes from ``4G``, ``512M``, ``1.5T``, ``4GiB``, ``4GB`` (powers of 1024: 4G = 4 GiB) or a number of bytes.

    Raises ValueError with the accepted forms on anything else (empty, negative, zero, unknown suffix, bool)."""
    if isinstance(value, bool):
        raise ValueError(f"expected a size such as 4G or a number of bytes, got {value!r}")
    if isinstance(value, (int, float)):
        number, unit = float(value), ""
    elif isinstance(value, str):
        m = _SIZE.match(value)
        if m is None:
            raise ValueError(
                f"invalid memory size {value!r}: use a number with an optional K, M, G or T suffix "
                "(powers of 1024), e.g. 512M or 4G"
            )
        number, unit = float(m.group(1)), m.group(2).upper()
    else:
        raise ValueError(f"expected a size such as 4G or a number of bytes, got {value!r}")
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"memory size must be > 0, got {value!r}")
    size = number * _UNITS[unit]
    if size < 1 or size > 2**62:
        raise ValueError(f"memory size {value!r} is out of range (1 byte to 4 EiB)")
    return int(size)


def format_bytes(n: float) -> str:
    """``1234567890`` → ``"1.15 GiB"`` (powers of 1024, three significant digits)."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            if unit == "B":
                return f"{int(n)} B"
            return f"{n:.3g} {unit}" if abs(n) >= 1 else f"{n:.2g} {unit}"
        n /= 1024
    return f"{n:.3g} TiB"  # pragma: no cover - the loop returns


# --------------------------------------------------------------------------- available memory


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except (OSError, ValueError):
        return None
    if text == "max":
        return None
    try:
        return int(text)
    except ValueError:
        return None


def _inactive_file(path: Path, key: str) -> int:
    try:
        for line in path.read_text().splitlines():
            name, _, value = line.partition(" ")
            if name == key:
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def _meminfo_available(meminfo: Path) -> int | None:
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                parts = line.split()
                return int(parts[1]) * 1024 if len(parts) > 2 and parts[2] == "kB" else int(parts[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_levels(root: Path, rel: str) -> list[Path]:
    """The cgroup folder of ``rel`` under ``root`` and its ancestors up to ``root`` (those that exist). Inside a
    container the mount shows the container's own cgroup as its root, so the path may not exist: then the root."""
    rel = rel.strip().lstrip("/")
    parts = [p for p in rel.split("/") if p] if rel else []
    levels = []
    for k in range(len(parts), -1, -1):
        d = root.joinpath(*parts[:k]) if k else root
        if d.is_dir():
            levels.append(d)
    return levels


def _cgroup_available(proc_cgroup: Path, sys_cgroup: Path) -> int | None:
    """Headroom left by the tightest cgroup memory limit of this process, or None when there is no limit."""
    try:
        lines = proc_cgroup.read_text().splitlines()
    except OSError:
        return None
    best: int | None = None
    for line in lines:
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        _, controllers, rel = fields
        if controllers == "":  # cgroup v2 (unified hierarchy)
            base = sys_cgroup if (sys_cgroup / "cgroup.controllers").exists() else sys_cgroup / "unified"
            files = ("memory.max", "memory.current", "memory.stat", "inactive_file")
        elif "memory" in controllers.split(","):
            base = sys_cgroup / "memory"
            files = ("memory.limit_in_bytes", "memory.usage_in_bytes", "memory.stat", "total_inactive_file")
        else:
            continue
        for d in _cgroup_levels(base, rel):
            limit = _read_int(d / files[0])
            if limit is None or limit >= 2**60:  # "max" or v1's "unlimited" (PAGE_COUNTER_MAX pages)
                continue
            usage = _read_int(d / files[1]) or 0
            usage -= min(_inactive_file(d / files[2], files[3]), usage)
            left = max(limit - usage, 0)
            best = left if best is None else min(best, left)
    return best


def available_memory(
    meminfo: str | Path = "/proc/meminfo",
    proc_cgroup: str | Path = "/proc/self/cgroup",
    sys_cgroup: str | Path = "/sys/fs/cgroup",
) -> tuple[int, str] | None:
    """(bytes the process may still allocate, what limits it: ``"MemAvailable"`` or ``"cgroup memory limit"``),
    or None where neither is known. The paths are parameters for tests."""
    avail = _meminfo_available(Path(meminfo))
    cg = _cgroup_available(Path(proc_cgroup), Path(sys_cgroup))
    if cg is not None and (avail is None or cg < avail):
        return cg, "cgroup memory limit"
    if avail is not None:
        return avail, "MemAvailable"
    return None


# --------------------------------------------------------------------------- the estimate


@dataclass(frozen=True)
class MemoryEstimate:
    """Estimated peak memory of one Newton step (bytes) and the counts it comes from."""

    backend: str
    counts: SymbolicCounts
    factor_bytes: int  # the factor as the backend stores it
    workspace_bytes: int  # transient factorisation workspace (update blocks, permuted copy of A)
    hessian_bytes: int  # the assembled Hessian with the copies and index maps kept of its pattern
    other_bytes: int  # dense vectors and contact sets
    margin_bytes: int = 0  # SAFETY_MARGIN of the sum of the others

    @property
    def total(self) -> int:
        return self.factor_bytes + self.workspace_bytes + self.hessian_bytes + self.other_bytes + self.margin_bytes

    def describe(self) -> str:
        c = self.counts
        return (
            f"Cholesky factor {format_bytes(self.factor_bytes + self.workspace_bytes)} for {c.n:,} DOFs "
            f"({c.nnz_factor:,} nonzeros), Hessian {format_bytes(self.hessian_bytes)} "
            f"({c.nnz_matrix:,} entries), vectors and contacts {format_bytes(self.other_bytes)}, "
            f"margin {format_bytes(self.margin_bytes)}"
        )

    def to_dict(self) -> dict[str, int | str]:
        c = self.counts
        return {
            "backend": self.backend,
            "dofs": c.n,
            "matrix_nonzeros": c.nnz_matrix,
            "factor_nonzeros": c.nnz_factor,
            "supernodes": c.supernodes,
            "factor_bytes": self.factor_bytes,
            "workspace_bytes": self.workspace_bytes,
            "hessian_bytes": self.hessian_bytes,
            "other_bytes": self.other_bytes,
            "margin_bytes": self.margin_bytes,
            "total_bytes": self.total,
        }


# Added to every estimate: without it the model came out 0.99-1.04x of the measured RSS growth of CHOLMOD runs (module
# docstring), so a limit set at the estimate could still be overrun by a few per cent.
SAFETY_MARGIN = 0.15


def step_overhead_bytes(num_dofs: int, collision_primitives: int = 0) -> int:
    """Dense vectors and contact sets of a step: 40 float64 vectors of all DOFs (positions, targets, gradients,
    directions, line-search trials, element scratch) and 1 KiB per collision-surface primitive (vertex, edge, face:
    broad-phase boxes and candidate pairs, collision sets)."""
    return 40 * 8 * int(num_dofs) + 1024 * int(collision_primitives)


class MemoryGuard:
    """Checks a step's estimated peak memory against the memory available before a factorisation allocates it.

    ``limit``: a user cap in bytes (``limit_label`` names it in the message, e.g. ``--max-memory 4G``);
    ``check_system``: also cap by :func:`available_memory`; ``other_bytes``: the step's dense vectors and contact
    sets (:func:`step_overhead_bytes`); ``available``: the system query (a parameter for tests)."""

    def __init__(
        self,
        limit: int | None = None,
        *,
        limit_label: str = "solver.max_memory",
        check_system: bool = True,
        other_bytes: int = 0,
        regrowth: float = 1.25,
        available: Callable[[], tuple[int, str] | None] = available_memory,
    ) -> None:
        self.limit = None if limit is None else int(limit)
        self.limit_label = limit_label
        self.check_system = bool(check_system)
        self.other_bytes = int(other_bytes)
        self.regrowth = float(regrowth)
        self._available = available
        self.checked_total = 0  # the largest estimate checked (and passed) so far
        self.checks = 0  # comparisons with the limits made
        self.last: MemoryEstimate | None = None
        self.peak: MemoryEstimate | None = None  # the largest estimate of the run

    def _limit(self) -> tuple[int, str] | None:
        options = []
        if self.limit is not None:
            options.append((self.limit, self.limit_label))
        if self.check_system:
            sys_avail = self._available()
            if sys_avail is not None:
                options.append(sys_avail)
        return min(options, key=lambda o: o[0]) if options else None

    def check(
        self,
        solver: LinearSolver,
        indptr: np.ndarray | None,
        indices: np.ndarray | None,
        n: int,
        perm: np.ndarray | None,
    ) -> MemoryEstimate | None:
        """Estimate the step for the pattern ``(indptr, indices)`` (CSR/CSC arrays holding both triangles)
        factorised in the order ``perm``; raise :class:`ResourceError` when it does not fit. ``perm`` None (the
        backend orders inside its own factorisation): nothing to count, skipped with a debug log."""
        if perm is None or indptr is None or indices is None:
            log.debug("memory check skipped: %s chooses its ordering inside the factorisation", solver.name)
            return None
        counts = symbolic_counts(indptr, indices, n, perm)
        est = solver.memory_estimate(counts, other_bytes=self.other_bytes)
        self.last = est
        if self.peak is None or est.total > self.peak.total:
            self.peak = est
        if self.checked_total and est.total <= self.regrowth * self.checked_total:
            return est
        limit = self._limit()
        if limit is None:
            log.debug("memory check skipped: no memory information and no limit (need ~%s)", format_bytes(est.total))
            self.checked_total = max(self.checked_total, est.total)
            return est
        self.checks += 1
        cap, source = limit
        log.debug("memory check: the step needs about %s (%s); %s available (%s)", format_bytes(est.total),
                  est.describe(), format_bytes(cap), source)  # fmt: skip
        if est.total > cap:
            raise ResourceError(self._message(est, cap, source))
        self.checked_total = max(self.checked_total, est.total)
        return est

    def _message(self, est: MemoryEstimate, cap: int, source: str) -> str:
        if source == self.limit_label:
            where = f"but the limit is {format_bytes(cap)} ({source})"
            raise_hint = "or raise solver.max_memory (idp run --max-memory)"
        else:
            where = f"but {format_bytes(cap)} are available (limit: {source})"
            raise_hint = "or run where more memory is free"
        return (
            f"not enough memory: the step needs about {format_bytes(est.total)} ({est.describe()}) {where}; "
            f"use a coarser mesh (fewer tets), fewer objects, {raise_hint}"
        )
