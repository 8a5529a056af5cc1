"""Byte-compile idp and the modules a run imports, as installing wheels does.

pip byte-compiles a wheel's modules when it installs them, so an installed idp imports from ``.pyc`` files. An
editable checkout (``pip install -e``, what ``make`` sets up) gets none at install time, and where
``PYTHONDONTWRITEBYTECODE`` is set (some CI and container images set it) the interpreter never writes them
either: every process then compiles the ~70 modules a scene run imports from source, about 0.15–0.2 s of the
start-up of each process on the 2-core VM (a sixth of bunny_700's fixed cost; measured with ``python -X importtime``
and cProfile's ``source_to_code``). ``make`` and ``idp bench`` call :func:`compile_package` so what is measured
and what a newcomer runs start like an installed idp. A read-only install is left as it is.

``make``'s first install (what ``make demo`` needs) does not byte-compile every dependency (``uv pip install
--compile-bytecode``: 6.5 s of the 2-core Intel VM's install, for ~4,700 files of which a run imports ~1,100):
:func:`compile_run_imports` writes the ``.pyc`` of just the modules a scene run imports (``python -m
idp._bytecode``, 2.6 s there in two processes); ``make test``'s install then byte-compiles the rest."""

from __future__ import annotations

import compileall
import importlib
import importlib.util
import io
import re
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

#: what a scene run imports, in two halves imported side by side (two processes): the CLI and API (the solver stack,
#: numba, scipy, ipctk, pydantic); the picture (matplotlib's Agg canvas) and the VTU writer (meshio), each imported
#: only when first needed, with the packages whose modules a run imports while compiling kernels (numba's compiler
#: passes, llvmlite's bindings), which importing does not reach: those are compiled whole, tests left out
RUN_IMPORTS: tuple[tuple[str, ...], tuple[str, ...]] = (("idp.cli", "idp.api"), ("idp.output.render", "meshio"))
COMPILER_PACKAGES = ("numba", "llvmlite")

_TESTS = re.compile(r"[/\\](tests?|testing)[/\\]")


def compile_package() -> bool:
    """Write (or refresh, when a source is newer) the ``.pyc`` of every module of the idp package; True when
    every module compiled. Quiet, and a no-op where the package folder cannot be written."""
    root = Path(__file__).resolve().parent
    try:
        with redirect_stdout(io.StringIO()):  # compileall reports failures on stdout; the caller's output stays clean
            return bool(compileall.compile_dir(root, quiet=1))
    except OSError:
        return False


def compile_run_imports(half: int | None = None) -> bool:
    """Write the ``.pyc`` of the modules a scene run imports (:data:`RUN_IMPORTS`, and the packages of
    :data:`COMPILER_PACKAGES`) besides idp's own: the first half in this process, the second in a child process at
    the same time (``half``: only that one, here). Importing writes the bytecode of every module it loads even where
    ``PYTHONDONTWRITEBYTECODE`` is set, as an install's byte-compiling would (each file is written whole and then
    renamed, so two processes may write one); a folder that cannot be written is skipped by the import system.
    True when everything compiled."""
    if half is None:
        child = subprocess.Popen([sys.executable, "-m", "idp._bytecode", "1"], stdin=subprocess.DEVNULL)
        ok = compile_package()  # (not short-circuited: a read-only idp still gets its dependencies compiled)
        ok = compile_run_imports(0) and ok
        return child.wait() == 0 and ok
    previous, sys.dont_write_bytecode = sys.dont_write_bytecode, False
    try:
        for name in RUN_IMPORTS[half]:
            importlib.import_module(name)
    finally:
        sys.dont_write_bytecode = previous
    ok = True
    for name in COMPILER_PACKAGES if half == 1 else ():
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            continue
        try:
            with redirect_stdout(io.StringIO()):
                ok = bool(compileall.compile_dir(Path(spec.origin).parent, quiet=1, rx=_TESTS)) and ok
        except OSError:
            ok = False
    return ok


if __name__ == "__main__":  # make's first install: python -m idp._bytecode (the child: ... 1)
    import os

    os.environ.setdefault("MPLBACKEND", "Agg")  # no display is probed while importing the picture module
    if len(sys.argv) > 1:
        sys.exit(0 if compile_run_imports(int(sys.argv[1])) else 1)
    if not compile_run_imports():  # not fatal: the modules then compile as they are imported
        print("idp: some modules could not be byte-compiled (read-only folder?)", file=sys.stderr)
