"""End-to-end scenes built to collide: every accepted Newton iterate must pass the independent certificate."""

import logging

import numpy as np
import pytest

from idp.api import simulate
from idp.contact.intersections import surface_intersecting_pairs
from idp.errors import IntersectingInputError, SolverError
from idp.scene.load import scene_from_dict


def scene(objects, *, dim=3, steps=6, tol=0.1, **extra):
    d = {
        "name": "t",
        "dim": dim,
        "time": {"h": 0.04**2, "steps": steps},
        "solver": {"newton_tol": tol, "check_every_iterate": True, "linear_solver": "auto"},
        "contact": {"dhat": 2e-3, "dhat_mode": "relative"},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": objects,
    }
    for k, v in extra.items():
        d.setdefault(k, {}).update(v) if isinstance(v, dict) else d.__setitem__(k, v)
    return scene_from_dict(d)


def grow(rate=0.15, steps=6):
    return {"growth_rate": rate, "growth_steps": steps}


def check_every_frame(result):
    recs = result.step_records
    assert recs, "no step ran"
    for r in recs:
        assert r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"], r["step"]
    return recs


def test_ball_grown_inside_a_box_touches_walls_and_stays_injective(tmp_path):
    s = scene(
        [
            {
                "name": "ball",
                "generate": {"shape": "ball", "radius": 0.35, "resolution": 3},
                "rest_shape": grow(0.2, 6),
            },
            {
                "name": "box",
                "kind": "obstacle",
                "generate": {"shape": "box_surface", "lo": [-0.5] * 3, "hi": [0.5] * 3, "resolution": 3},
            },
        ],
        steps=8,
    )
    res = simulate(s, tmp_path, progress=False)
    recs = check_every_frame(res)
    assert max(r["contacts"] for r in recs) > 0, "the scene was meant to collide"
    assert res.summary["fill_fraction"] > recs[0]["fill_fraction"] if recs[0]["fill_fraction"] else True
    ball = res.x[res.parts[0].vertex_ids]
    # ball stays inside the box (barrier, not a clamp): every vertex strictly inside, some very close to a wall
    assert np.all(np.abs(ball) < 0.5)
    assert np.abs(ball).max() > 0.49
    assert res.summary["all_certified"]


def test_two_blocks_pressed_together_every_iterate_certified(tmp_path):
    s = scene(
        [
            {
                "name": "left",
                "generate": {
                    "shape": "tet_box",
                    "lo": [-0.45, -0.2, -0.2],
                    "hi": [-0.02, 0.2, 0.2],
                    "resolution": [3, 3, 3],
                },
                "rest_shape": grow(0.15, 5),
            },
            {
                "name": "right",
                "generate": {
                    "shape": "tet_box",
                    "lo": [0.02, -0.2, -0.2],
                    "hi": [0.45, 0.2, 0.2],
                    "resolution": [3, 3, 3],
                },
                "rest_shape": grow(0.15, 5),
                "material": {
                    "model": "symmetric_dirichlet",
                    "youngs_modulus": 1e4,
                    "poisson_ratio": 0.3,
                    "density": 1000.0,
                },
            },
            {
                "name": "cage",
                "kind": "obstacle",
                "generate": {"shape": "box_surface", "lo": [-0.5] * 3, "hi": [0.5] * 3, "resolution": 2},
            },
        ],
        steps=6,
    )
    res = simulate(s, tmp_path, progress=False)
    recs = check_every_frame(res)
    assert max(r["contacts"] for r in recs) > 0
    # the two blocks press against each other: their facing surfaces end up closer than the start gap
    assert res.summary["min_distance"] < 0.04


def test_2d_disk_in_circle_neo_hookean(tmp_path):
    s = scene(
        [
            {
                "name": "disk",
                "generate": {"shape": "disk", "radius": 0.3, "resolution": 4},
                "rest_shape": grow(0.2, 6),
                "scale": 1.0,
                "translate": [0.1, 0.0],
            },
            {
                "name": "ring",
                "kind": "obstacle",
                "generate": {"shape": "circle_polygon", "radius": 0.5, "segments": 48},
            },
        ],
        dim=2,
        steps=8,
    )
    res = simulate(s, tmp_path, progress=False)
    recs = check_every_frame(res)
    assert max(r["contacts"] for r in recs) > 0
    disk = res.x[res.parts[0].vertex_ids]
    assert np.linalg.norm(disk, axis=1).max() < 0.5


def test_intersecting_input_refused_by_default_and_preserved_on_request(tmp_path):
    objs = [
        {"name": "a", "generate": {"shape": "ball", "radius": 0.3, "resolution": 2}},
        {
            "name": "b",
            "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
            "translate": [0.4513, 0.0217, 0.0131],
            "rotate": [{"axis": [0.3, 1.0, 0.2], "degrees": 17.0}],
        },
    ]
    with pytest.raises(IntersectingInputError) as err:
        simulate(scene(objs, steps=2), tmp_path / "refused", progress=False)
    msg = str(err.value)
    assert "intersecting surface primitive pair" in msg and "a:" in msg and "b:" in msg
    s = scene([dict(o, rest_shape=grow(0.1, 3)) for o in objs], steps=3, contact={"preserve_input_intersections": True})
    res = simulate(s, tmp_path / "kept", progress=False)
    check_every_frame(res)
    # the input intersection is preserved (never removed), and the run still guards everything else
    surf = np.vstack([p.surface for p in res.parts])
    assert len(surface_intersecting_pairs(res.x, surf)) > 0


def test_iteration_cap_is_reported_not_called_converged(tmp_path, caplog):
    objs = [{"name": "ball", "generate": {"shape": "ball", "radius": 0.3, "resolution": 2}, "rest_shape": grow(0.5, 2)}]
    s = scene(objs, steps=2, tol=1e-12, solver={"max_newton_iterations": 1})
    with caplog.at_level(logging.WARNING, logger="idp"):
        res = simulate(s, tmp_path / "warn", progress=False)
    assert res.summary["nonconverged_steps"] == 2
    assert all(r["hit_iteration_cap"] and not r["converged"] for r in res.step_records)
    assert "did not converge" in caplog.text
    s = scene(objs, steps=2, tol=1e-12, solver={"max_newton_iterations": 1, "on_nonconvergence": "error"})
    with pytest.raises(SolverError):
        simulate(s, tmp_path / "err", progress=False)


def test_stationary_stop_and_resume(tmp_path):
    objs = [{"name": "ball", "generate": {"shape": "ball", "radius": 0.3, "resolution": 2}, "rest_shape": grow(0.1, 2)}]
    s = scene(objs, steps=50, tol=1e-3, time={"stop_when_stationary": True, "stationary_tol": 1e-4})
    res = simulate(s, tmp_path / "stat", progress=False)
    assert res.summary["steps_run"] < 50 and res.summary["stopped"].startswith("stationary")
    # resume: 2 steps, then continue to 4 from the checkpoint
    s = scene(objs, steps=4, tol=1e-3)
    simulate(s, tmp_path / "res", steps=2, progress=False)
    res2 = simulate(s, tmp_path / "res", steps=4, progress=False, resume=True)
    assert [r["step"] for r in res2.step_records] == [1, 2, 3, 4]  # the earlier steps are kept
    assert res2.summary["steps_run"] == 4 and res2.summary["newton_iterations"] == sum(
        r["newton_iterations"] for r in res2.step_records
    )


def test_fixed_vertices_by_box_and_indices_do_not_move(tmp_path):
    objs = [
        {
            "name": "slab",
            "generate": {"shape": "tet_box", "lo": [-0.3, -0.1, -0.3], "hi": [0.3, 0.1, 0.3], "resolution": [3, 2, 3]},
            "rest_shape": {
                "scale": [1.0, 1.5, 1.0]
            },  # wants to be 1.5× taller: it stretches away from the pinned bottom
            "fixed": [{"box": [[-1, -0.2, -1], [1, -0.09, 1]]}, {"indices": [5]}],
        }
    ]
    s = scene(objs, steps=3, tol=1e-2)
    res = simulate(s, tmp_path, progress=False)
    from idp.mesh.generate import tet_box

    x0 = tet_box((-0.3, -0.1, -0.3), (0.3, 0.1, 0.3), (3, 2, 3)).vertices
    bottom = np.flatnonzero(x0[:, 1] < -0.09)
    assert bottom.size > 0
    assert np.array_equal(res.x[bottom], x0[bottom]) and np.array_equal(res.x[5], x0[5])
    top = np.flatnonzero(x0[:, 1] > 0.09)
    assert res.x[top, 1].mean() > 0.1 + 0.02  # the free part moved
