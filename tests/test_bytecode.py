"""idp._bytecode: the package's modules byte-compiled as a wheel install leaves them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

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
