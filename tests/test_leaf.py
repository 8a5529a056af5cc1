"""Compiled helpers without reference counting (idp._leaf): they may not return arrays nor allocate them."""

import numpy as np
import pytest

from idp._leaf import LEAVES, array_returning_leaves, compiled_leaves, leaf_njit, load_cached_leaves
from idp.api import simulate
from idp.bench.suite import _ball_in_box
from idp.scene.load import scene_from_dict


def test_a_leaf_returning_an_array_is_reported():
    @leaf_njit()
    def first_row(a):  # numba itself refuses a view (a[0]) but lets the argument through
        return a

    try:
        first_row(np.ones((2, 3)))  # compiles: numba itself does not object
        assert any("first_row" in s for s in array_returning_leaves())
    finally:
        LEAVES.remove(first_row)
    assert not any("first_row" in s for s in array_returning_leaves())


def test_a_leaf_cannot_allocate():
    @leaf_njit()
    def scratch(n):
        return np.empty(n).size

    try:
        with pytest.raises(Exception, match="empty"):
            scratch(3)
    finally:
        LEAVES.remove(scratch)


def test_the_kernels_leaves_on_a_colliding_scene_return_no_arrays(tmp_path):
    """A tet ball grown against a box (elastic element pass, inversion filter, broad phase, CCD bounds, barrier
    Hessians with PSD projection, certificate) compiles its leaves, or they are in numba's cache already: every
    leaf signature compiled on this machine (by this scene or by the tests before it) returns scalars or nothing."""
    scene = _ball_in_box("leaves", 0.3, 4)  # a generated ball grown into a box's walls
    scene["time"]["steps"] = 4
    s = scene_from_dict(scene)
    res = simulate(s, tmp_path, progress=False)
    assert max(r["contacts"] for r in res.step_records) > 0, "the scene was meant to collide"
    assert res.summary["all_certified"]
    load_cached_leaves()  # leaves of kernels that were loaded whole from the cache
    assert compiled_leaves() >= 20
    assert array_returning_leaves() == []
