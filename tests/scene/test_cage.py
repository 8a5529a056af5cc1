"""Which static obstacle is a cage (its enclosed volume gives the fill fraction): one that holds the bodies."""

from __future__ import annotations

import pytest

from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _two_balls() -> dict:
    return {
        "name": "cage",
        "dim": 3,
        "output": {"png": False, "obj": False, "vtu": False},
        "objects": [
            {
                "name": f"ball_{k}",
                "generate": {"shape": "ball", "radius": 0.2, "resolution": 2},
                "translate": [sx, 0, 0],
            }
            for k, sx in enumerate((-0.21, 0.21))
        ],
    }


def test_only_an_obstacle_holding_the_bodies_is_a_cage():
    d = _two_balls()
    plate = {"name": "plate", "kind": "obstacle"}
    plate["generate"] = {"shape": "box_surface", "lo": [-1, -0.4, -1], "hi": [1, -0.3, 1], "resolution": 2}
    d["objects"] = [*d["objects"], plate]
    assert build_scene(scene_from_dict(d)).system.meta["cage_volume"] is None  # a plate beside them: no fill
    box = {"name": "box", "kind": "obstacle"}
    box["generate"] = {"shape": "box_surface", "lo": [-1, -1, -1], "hi": [1, 1, 1], "resolution": 2}
    d["objects"] = [*d["objects"][:2], box]
    assert build_scene(scene_from_dict(d)).system.meta["cage_volume"] == pytest.approx(8.0)
