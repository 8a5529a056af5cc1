"""The machine a benchmark ran on, described well enough to compare runs across machines.

``describe()`` returns a JSON-ready dict: CPU model string, clock (MHz), logical / physical core
counts, cache size (from /proc/cpuinfo on Linux, falling back to :mod:`platform`), numba's target
CPU, the thread settings (NUMBA / OMP / OPENBLAS / MKL), and the versions of Python and of the
numerical libraries.  ``summary()`` renders it as Markdown lines for a results table's header.
"""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path

THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
PACKAGES = ("numpy", "scipy", "numba", "llvmlite", "ipctk", "cvxopt", "pymetis")


def parse_cpuinfo(text: str) -> dict:
    """CPU model, clock, cache and core counts from the text of /proc/cpuinfo (missing fields: None)."""
    model = mhz = cache = None
    logical = 0
    cores: set[tuple[str, str]] = set()
    physical_id = core_id = ""
    for line in [*text.splitlines(), ""]:
        if not line.strip():  # end of one processor block
            if core_id:
                cores.add((physical_id, core_id))
            physical_id = core_id = ""
            continue
        key, _, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if key == "processor":
            logical += 1
        elif key in ("model name", "Model", "cpu model") and model is None:
            model = value
        elif key == "cpu MHz" and mhz is None:
            try:
                mhz = float(value)
            except ValueError:
                pass
        elif key == "cache size" and cache is None:
            cache = value
        elif key == "physical id":
            physical_id = value
        elif key == "core id":
            core_id = value
    return {
        "cpu_model": model,
        "cpu_mhz": mhz,
        "cache_size": cache,
        "logical_cores": logical or None,
        "physical_cores": len(cores) or None,
    }


def _numba_target_cpu() -> str | None:
    try:
        from numba.core import config

        name = getattr(config, "CPU_NAME", None)  # set by NUMBA_CPU_NAME (e.g. "generic")
        if name:
            return str(name)
        import llvmlite.binding as llvm

        return str(llvm.get_host_cpu_name())
    except Exception:  # numba / llvmlite missing or broken: leave it out rather than fail a benchmark
        return None


def _numba_threads() -> int | None:
    try:
        import numba

        return int(getattr(numba.config, "NUMBA_NUM_THREADS"))  # noqa: B009 (set at import, unknown to mypy)
    except Exception:
        return None


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def _cholmod_version() -> str | None:
    """CHOLMOD's version as cvxopt reports it (not every cvxopt build exposes it)."""
    try:
        from cvxopt import cholmod
    except Exception:
        return None
    for attr in ("__version__", "version", "CHOLMOD_VERSION"):
        v = getattr(cholmod, attr, None)
        if v is not None:
            return str(v() if callable(v) else v)
    return f"bundled with cvxopt {_version('cvxopt') or '?'} (version not exposed)"


def _cholmod_blas() -> str | None:
    """Which BLAS CHOLMOD's dense kernels run on in a process like this one (routing is tried as a run would)."""
    try:
        import numba

        from idp.solver import cholmod_blas

        cholmod_blas.route_cholmod_blas(numba.get_num_threads())
        return cholmod_blas.STATUS
    except ImportError:
        return None


def describe(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict:
    """The machine description (see the module docstring)."""
    try:
        cpu = parse_cpuinfo(cpuinfo.read_text())
    except OSError:
        cpu = parse_cpuinfo("")
    if not cpu["cpu_model"]:
        cpu["cpu_model"] = platform.processor() or platform.machine() or None
    if not cpu["logical_cores"]:
        cpu["logical_cores"] = os.cpu_count()
    versions: dict[str, str | None] = {"python": platform.python_version()}
    versions.update({name: _version(name) for name in PACKAGES})
    versions["cholmod"] = _cholmod_version()
    versions["cholmod_blas"] = _cholmod_blas()
    return {
        **cpu,
        "platform": f"{platform.system()} {platform.release()} {platform.machine()}",
        "numba_target_cpu": _numba_target_cpu(),
        "numba_threads": _numba_threads(),
        "thread_env": {v: os.environ.get(v) for v in THREAD_VARIABLES},
        "versions": versions,
    }


def summary(m: dict) -> list[str]:
    """Markdown lines describing the machine ``m`` (from :func:`describe`) for a results header."""
    mhz = f"{m['cpu_mhz']:.0f} MHz" if m.get("cpu_mhz") else "clock unknown"
    cores = f"{m.get('logical_cores') or '?'} logical / {m.get('physical_cores') or '?'} physical cores"
    env = ", ".join(f"{k}={v}" for k, v in m.get("thread_env", {}).items() if v is not None) or "none set"
    vers = ", ".join(f"{k} {v}" for k, v in m.get("versions", {}).items() if v is not None)
    return [
        f"**Machine:** {m.get('cpu_model') or 'unknown CPU'}, {mhz}, {cores}, cache {m.get('cache_size') or '?'}; "
        f"{m.get('platform', '')}",
        f"**numba:** target CPU {m.get('numba_target_cpu') or '?'}, {m.get('numba_threads') or '?'} threads "
        f"(thread variables: {env})",
        f"**Versions:** {vers}",
    ]
