"""idp._bytecode: idp and what a run imports byte-compiled, as a wheel install leaves them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

import idp
from idp import _bytecode


def test_every_module_gets_current_bytecode() -> None:
    assert _bytecode.compile_package()
    root = Path(idp.__file__).resolve().parent
    for src in (root / "api.py", root / "contact" / "model.py", root / "solver" / "newton.py"):
        pyc = Path(importlib.util.cache_from_source(str(src)))
        assert pyc.is_file(), f"no bytecode for {src}"
        assert pyc.stat().st_mtime >= src.stat().st_mtime  # not older than its source: the import uses it


def test_unwritable_package_is_left_alone(monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise PermissionError("read-only install")

    monkeypatch.setattr(_bytecode.compileall, "compile_dir", refuse)
    assert _bytecode.compile_package() is False


def test_what_a_run_imports_gets_bytecode() -> None:
    """``python -m idp._bytecode`` (make's first install): the modules a run imports, idp's own and numba's
    compiler passes (imported only while compiling kernels) end up byte-compiled, even with
    PYTHONDONTWRITEBYTECODE set."""
    import os
    import subprocess
    import sys

    import meshio
    import numba.core.typed_passes
    import scipy.sparse

    pycs = [
        Path(importlib.util.cache_from_source(str(m.__file__)))
        for m in (meshio, numba.core.typed_passes, scipy.sparse, idp)
    ]
    if not all(os.access(p.parent, os.W_OK) for p in pycs):
        pytest.skip("a read-only install: nothing is written there")
    for p in pycs:
        p.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    subprocess.run([sys.executable, "-m", "idp._bytecode"], check=True, env=env, timeout=300)
    for p in pycs:
        assert p.is_file(), f"no bytecode {p}"
