"""Byte-compile idp's own modules, as installing a wheel does.

pip byte-compiles a wheel's modules when it installs them, so an installed idp imports from ``.pyc`` files. An
editable checkout (``pip install -e``, what ``make`` sets up) gets none at install time, and where
``PYTHONDONTWRITEBYTECODE`` is set (some CI and container images set it) the interpreter never writes them
either: every process then compiles the ~70 modules a scene run imports from source, about 0.15–0.2 s of the
start-up of each process on the 2-core VM (a sixth of bunny_700's fixed cost; measured with ``python -X importtime``
and cProfile's ``source_to_code``). ``make`` and ``idp bench`` call :func:`compile_package` so what is measured
and what a newcomer runs start like an installed idp. A read-only install is left as it is."""

from __future__ import annotations

import compileall
import io
from contextlib import redirect_stdout
from pathlib import Path


def compile_package() -> bool:
    """Write (or refresh, when a source is newer) the ``.pyc`` of every module of the idp package; True when
    every module compiled. Quiet, and a no-op where the package folder cannot be written."""
    root = Path(__file__).resolve().parent
    try:
        with redirect_stdout(io.StringIO()):  # compileall reports failures on stdout; the caller's output stays clean
            return bool(compileall.compile_dir(root, quiet=1))
    except OSError:
        return False
