"""Islands of a Newton move (idp.solver.islands): bodies that cannot meet along a move each take their own step
length, so a body whose move CCD cuts short no longer holds back one that falls freely; the step's minimiser and
its certificate are unchanged."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from idp.api import simulate
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict
from idp.solver.islands import body_labels, merge_labels


def _floor(name: str, x0: float) -> dict[str, Any]:
    return {
        "name": name,
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [x0 - 0.3, -0.1, -0.3], "hi": [x0 + 0.3, 0.0, 0.3], "resolution": 4},
    }


def _ball(name: str, x0: float, y0: float, youngs_modulus: float) -> dict[str, Any]:
    return {
        "name": name,
        "generate": {"shape": "ball", "radius": 0.1, "resolution": 3},
        "translate": [x0, y0, 0.0],
        "material": {"youngs_modulus": youngs_modulus, "density": 1000.0},
    }


def _scene(island_steps: bool, steps: int = 2) -> dict[str, Any]:
    """Two balls 1 apart, each landing on its own floor in the first step, at other Newton iterations: ball A
    0.02 above its floor, ball B, softer, 0.03 above."""
    return {
        "name": "islands",
        "dim": 3,
        "gravity": [0.0, -9.8, 0.0],
        "time": {"h": 1e-2, "steps": steps},
        "contact": {"dhat": 1e-3},
        # every accepted Newton iterate certified intersection- and inversion-free, not only every frame
        "solver": {"island_steps": island_steps, "check_every_iterate": True},
        "output": {"png": False, "obj": False, "vtu": False},
        "objects": [
            _ball("ball_a", 0.0, 0.12, 1e4),
            _ball("ball_b", 1.0, 0.13, 3e3),
            _floor("floor_a", 0.0),
            _floor("floor_b", 1.0),
        ],
    }


def test_body_labels_give_each_body_its_label_and_obstacles_none():
    built = build_scene(scene_from_dict(_scene(True)))
    labels = body_labels(built.system)
    assert labels.num_labels == 2
    ids = {p.name: p.vertex_ids for p in built.system.parts}
    for name in ("ball_a", "ball_b"):
        lab = np.unique(labels.vertex_label[ids[name]])
        assert lab.size == 1 and lab[0] >= 0, name
    assert np.unique(labels.vertex_label[ids["ball_a"]])[0] != np.unique(labels.vertex_label[ids["ball_b"]])[0]
    for floor in ("floor_a", "floor_b"):
        assert np.all(labels.vertex_label[ids[floor]] == -1)  # no free DOF: takes no part in any move
    assert [t.size for t in labels.term_labels] == [1, 1]


def test_a_pair_term_joins_the_bodies_it_links():
    built = build_scene(scene_from_dict(_scene(True)))
    system = built.system

    class Link:  # the one thing body_labels reads of a pair term
        pairs = np.array([[int(system.parts[0].vertex_ids[0]), int(system.parts[1].vertex_ids[0])]])

    system.pair_terms.append(Link())
    try:
        assert body_labels(system).num_labels == 1
    finally:
        system.pair_terms.pop()


@pytest.mark.parametrize(
    ("groups", "expect"),
    [
        (np.zeros((0, 4), dtype=np.int64), [0, 1, 2, 3]),  # nothing joins: every label its own island
        (np.array([[0, 2, -1, -1]]), [0, 1, 0, 2]),
        (np.array([[-1, -1, -1, -1], [3, 3, 1, -1]]), [0, 1, 2, 1]),
        (np.array([[0, 1, -1, -1], [2, 3, -1, -1], [1, 2, -1, -1]]), [0, 0, 0, 0]),
    ],
)
def test_merge_labels_joins_the_labels_of_each_row(groups, expect):
    count, island = merge_labels(4, groups)
    # the same partition as expected, whatever the islands' numbering
    assert count == len(set(expect))
    for i in range(4):
        for j in range(4):
            assert (island[i] == island[j]) == (expect[i] == expect[j]), (i, j)


def test_a_body_is_not_held_back_by_another_landing_elsewhere(tmp_path):
    runs = {
        flag: simulate(scene_from_dict(_scene(flag)), tmp_path / str(flag), progress=False) for flag in (True, False)
    }
    for flag, res in runs.items():
        assert res.summary["all_certified"], flag
        assert all(r["converged"] for r in res.step_records if not r.get("initial")), flag
    split = [r for r in runs[True].step_records if not r.get("initial")]
    whole = [r for r in runs[False].step_records if not r.get("initial")]
    # both land in the first step: CCD cuts their moves, and without islands each ball's cuts stop the other too
    assert min(whole[0]["ccd_alphas"]) < 0.5
    assert split[0]["island_iterations"] > 0 and split[0]["max_islands"] == 2
    # each ball's contact look-ahead switched on by its own cut moves (one switch per body)
    assert split[0]["lookahead_iterations"] > 0
    assert all(r["island_iterations"] == 0 for r in whole)
    assert sum(r["newton_iterations"] for r in split) < sum(r["newton_iterations"] for r in whole)
    # the same minimiser, up to the stopping rule (max |p| / √h ≤ 1e-2: moves left of ~1e-3 at h = 1e-2)
    ids = {p.name: p.vertex_ids for p in runs[True].parts}
    for name in ("ball_a", "ball_b"):
        gap = np.abs(runs[True].x[ids[name]] - runs[False].x[ids[name]]).max()
        assert gap < 5e-3, (name, gap)
    for name in ("ball_a", "ball_b"):  # both rest on their floors
        assert runs[True].x[ids[name], 1].min() == pytest.approx(0.0, abs=2e-3), name
