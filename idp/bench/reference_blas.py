"""Which OpenBLAS kernels the reference's CHOLMOD runs on, and a fair choice when its OpenBLAS does not know the CPU.

OpenBLAS built with ``DYNAMIC_ARCH`` picks its kernels from the CPU model when it is loaded. A release older than
the CPU does not know the model and falls back to its generic SSE3 kernels ("Prescott"). The prebuilt reference
links Debian 12's OpenBLAS 0.3.21, which on a 2-core Emerald Rapids Xeon VM (family 6, model 207; AVX-512) does
exactly that, while idp's CHOLMOD runs on scipy's OpenBLAS 0.3.30, which picks its SkylakeX kernels there
(idp/solver/cholmod_blas.py). Measured on that VM, the reference's bunnyx30_13K run took 1,385 s on its fallback
kernels (linear solve 2.17 s per Newton iteration) and 1,018 s with ``OPENBLAS_CORETYPE=SkylakeX`` (1.26 s): a
side-by-side ratio would otherwise measure the two OpenBLAS releases' CPU tables, not the two codes.

So before a reference run the bench asks the reference's OpenBLAS (loaded in a small child process with the
reference's environment) which kernels it picks. When that is a generic fallback on a CPU with AVX2 and FMA (which
the prebuilt reference requires anyway), the reference runs with ``OPENBLAS_CORETYPE`` set to the kernels idp's
OpenBLAS uses, or the best one its release accepts (SkylakeX with AVX-512, else Haswell), checked the same way.
Policies: ``auto`` (that), ``as-is`` (never set it), or a core name to force. The outcome is recorded with every
reference run.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
from pathlib import Path

from idp.solver.cholmod_blas import scipy_openblas_path

#: The cores OpenBLAS falls back to when it does not recognise a CPU (or on old ones): SSE2/SSE3 kernels only.
GENERIC_CORES = frozenset({"prescott", "core2", "katmai", "northwood", "banias", "penryn", "dunnington", "atom"})

#: The reference's OpenBLAS as the dynamic linker finds it (Debian's alternatives: the pthreads build).
REFERENCE_LIBRARIES = ("libopenblas.so.0", "libblas.so.3")

_PROBE = """
import ctypes, sys
for name in sys.argv[1:]:
    try:
        lib = ctypes.CDLL(name)
        get = lib.openblas_get_corename
    except (OSError, AttributeError):
        continue
    get.restype = ctypes.c_char_p
    print(get().decode())
    break
"""


def reference_core(env: dict[str, str] | None = None) -> str | None:
    """The kernels the reference's OpenBLAS picks under ``env`` (None: not OpenBLAS, or not found)."""
    try:
        out = subprocess.run(
            [sys.executable, "-c", _PROBE, *REFERENCE_LIBRARIES],
            env=dict(os.environ if env is None else env),
            capture_output=True,
            text=True,
            timeout=60,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    name = out.stdout.strip().splitlines()
    return name[-1] if out.returncode == 0 and name else None


def idp_core() -> str | None:
    """The kernels scipy's OpenBLAS picks here (the BLAS idp routes CHOLMOD to); None when it is not found."""
    try:
        path = scipy_openblas_path()
        if path is None:
            return None
        get = ctypes.CDLL(path).scipy_openblas_get_corename
        get.restype = ctypes.c_char_p
        return get().decode()
    except (OSError, AttributeError, ImportError):
        return None


def _cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> set[str]:
    try:
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _candidates(flags: set[str]) -> list[str]:
    """Cores to try in order: idp's own, then the widest this CPU runs."""
    out = []
    ours = idp_core()
    if ours and ours.lower() not in GENERIC_CORES:
        out.append(ours)
    if {"avx512f", "avx512dq", "avx512bw", "avx512vl", "avx512cd"} <= flags:
        out.append("SkylakeX")
    if {"avx2", "fma"} <= flags:
        out.append("Haswell")
    return list(dict.fromkeys(out))


def choose_reference_blas(env: dict[str, str], policy: str = "auto") -> tuple[dict[str, str], dict]:
    """The environment to run the reference with, and a record of the choice: ``{"policy", "default_core",
    "core", "forced"}`` (``core``: what its OpenBLAS uses under the returned environment)."""
    env = dict(env)
    if policy == "as-is":
        core = reference_core(env)
        return env, {"policy": policy, "default_core": core, "core": core, "forced": None}
    base = {k: v for k, v in env.items() if k != "OPENBLAS_CORETYPE"}
    default = reference_core(base)
    record = {"policy": policy, "default_core": default, "core": default, "forced": None}
    if default is None:
        return base, record
    if policy == "auto":
        if default.lower() not in GENERIC_CORES:
            return base, record
        tries = _candidates(_cpu_flags())
    else:
        tries = [policy]
    for name in tries:
        trial = dict(base, OPENBLAS_CORETYPE=name)
        got = reference_core(trial)
        if got is not None and got.lower() == name.lower():
            record.update(core=got, forced=name)
            return trial, record
    if policy != "auto":
        raise ValueError(f"the reference's OpenBLAS does not accept OPENBLAS_CORETYPE={policy} (it keeps {default})")
    return base, record


def describe_choice(record: dict | None) -> str:
    """One line for the report."""
    if not record or record.get("default_core") is None:
        return "the reference's BLAS: not OpenBLAS, or not found"
    if record.get("forced"):
        return (
            f"the reference's OpenBLAS picks {record['default_core']} kernels on this CPU by itself; run with "
            f"OPENBLAS_CORETYPE={record['forced']} ({record['policy']})"
        )
    return f"the reference's OpenBLAS uses its {record['core']} kernels ({record['policy']})"
