"""Checks on the paper's own meshes; skipped with a message when the data is absent ($IDP_DATA or ../shared/data)."""

import itertools

import pytest

from idp.bench.data import find_data_dir

DATA = find_data_dir()
pytestmark = pytest.mark.skipif(
    DATA is None, reason="the paper's data was not found: set IDP_DATA (e.g. ../shared/data)"
)


def test_obj_files_meshio_rejects_are_read():
    from idp.mesh.io import read_mesh
    from idp.mesh.surface import surface_topology

    for name, nv in (("nice_cube.obj", 386), ("hourglass.obj", 4552)):
        m = read_mesh(DATA / "benchmark" / name, kind="surface")
        assert m.vertices.shape[0] == nv
        assert surface_topology(m.faces, nv).is_closed


def test_bunny_in_box_first_steps_are_certified(tmp_path):
    from idp.api import simulate
    from idp.bench.scenes import bunny_in_box

    res = simulate(bunny_in_box(DATA, "bunny_700.vtk", 10.0), tmp_path, steps=4, progress=False)
    assert res.summary["all_certified"]
    fills = [r["fill_fraction"] for r in res.step_records]
    assert all(b > a for a, b in itertools.pairwise(fills))  # growing
    assert 0.09 < fills[0] < 0.2
