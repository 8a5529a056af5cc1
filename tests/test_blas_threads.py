"""numpy's / scipy's BLAS pools run one thread while a run steps (idp._blas_threads), whatever the import order."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from threadpoolctl import ThreadpoolController, threadpool_limits

import idp.stepper.run as run_module
from idp._blas_threads import quiet_blas


def _numpy_blas():
    return [lib for lib in ThreadpoolController().lib_controllers if lib.user_api == "blas" and "numpy" in lib.filepath]


def _two_threads_or_skip():
    libs = _numpy_blas()
    if not libs:
        pytest.skip("numpy's BLAS is not an OpenBLAS that threadpoolctl can see")
    limits = threadpool_limits(2, user_api="blas")
    if max(lib.num_threads for lib in _numpy_blas()) < 2:
        limits.restore_original_limits()
        pytest.skip("numpy's BLAS cannot run two threads on this machine")
    return limits


def test_quiet_blas_limits_numpy_blas_to_one_thread_and_restores_it():
    limits = _two_threads_or_skip()
    try:
        before = [lib.num_threads for lib in _numpy_blas()]
        with quiet_blas():
            assert all(lib.num_threads == 1 for lib in _numpy_blas())
        assert [lib.num_threads for lib in _numpy_blas()] == before
    finally:
        limits.restore_original_limits()


def test_quiet_blas_restores_after_an_exception():
    limits = _two_threads_or_skip()
    try:
        before = [lib.num_threads for lib in _numpy_blas()]
        with pytest.raises(RuntimeError), quiet_blas():
            raise RuntimeError("a run that stops")
        assert [lib.num_threads for lib in _numpy_blas()] == before
    finally:
        limits.restore_original_limits()


def test_run_simulation_steps_under_quiet_blas(monkeypatch, tmp_path):
    limits = _two_threads_or_skip()
    seen = []

    def first_thing_the_run_makes(*args, **kwargs):  # the default frame writer: record, then stop the run
        seen.append([lib.num_threads for lib in _numpy_blas()])
        raise RuntimeError("stop here")

    monkeypatch.setattr(run_module, "FrameWriter", first_thing_the_run_makes)
    system = SimpleNamespace(parts=[], dim=3, free_mask=np.zeros(3, dtype=bool))
    try:
        with pytest.raises(RuntimeError, match="stop here"):
            run_module.run_simulation(
                system, None, None, None, tmp_path, SimpleNamespace(write_obj=True, write_vtu=True)
            )
        assert seen and all(n == 1 for n in seen[0])
        assert all(lib.num_threads >= 2 for lib in _numpy_blas())
    finally:
        limits.restore_original_limits()
