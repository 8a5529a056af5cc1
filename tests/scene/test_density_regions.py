"""Per-region density (paper §7.5's light flower heads): elements wholly inside a region get its density, the
lumped masses follow, and bad regions are refused naming the key."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from idp.errors import SceneError
from idp.mesh.quality import signed_volumes
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _scene(regions: list[dict], **obj) -> dict[str, Any]:
    ball = {
        "name": "ball",
        "generate": {"shape": "ball", "radius": 0.5, "resolution": 3},
        "material": {"density": 1000.0},
        "density_regions": regions,
    }
    ball.update(obj)
    return {"name": "rho", "dim": 3, "output": {"png": False}, "objects": [ball]}


def test_region_elements_get_their_density_and_the_masses_follow():
    top = {"select": {"box": [[0.0, 0.5, 0.0], [1.0, 1.0, 1.0]], "relative": True}, "density": 20.0}
    built = build_scene(scene_from_dict(_scene([top])))
    s = built.system
    x, tets = s.x, s.bodies[0].elastic.elements
    vol = signed_volumes(x, tets)
    inside = (x[tets][:, :, 1] >= -1e-12).all(axis=1)  # the upper half: y ≥ 0 (the ball is centred at 0)
    assert 0 < inside.sum() < tets.shape[0]
    want = 1000.0 * vol[~inside].sum() + 20.0 * vol[inside].sum()
    assert s.masses.sum() == pytest.approx(want, rel=1e-12)
    # a vertex touched only by region elements carries a 50× lighter share than one touched only by others
    only_in = np.setdiff1d(np.unique(tets[inside]), np.unique(tets[~inside]))
    only_out = np.setdiff1d(np.unique(tets[~inside]), np.unique(tets[inside]))
    per_vol = np.bincount(tets.ravel(), weights=np.repeat(vol / 4, 4), minlength=x.shape[0])
    np.testing.assert_allclose(s.masses[only_in] / per_vol[only_in], 20.0, rtol=1e-12)
    np.testing.assert_allclose(s.masses[only_out] / per_vol[only_out], 1000.0, rtol=1e-12)


def test_later_regions_win_and_exclude_works():
    every = {"select": {"box": [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], "relative": True}, "density": 5.0}
    core = {"select": {"sphere": {"center": [0.0, 0.0, 0.0], "radius": 0.3}}, "density": 7.0}
    s = build_scene(scene_from_dict(_scene([every, core]))).system
    x, tets = s.x, s.bodies[0].elastic.elements
    vol = signed_volumes(x, tets)
    in_core = (np.linalg.norm(x[tets], axis=2) <= 0.3).all(axis=1)
    assert s.masses.sum() == pytest.approx(5.0 * vol[~in_core].sum() + 7.0 * vol[in_core].sum(), rel=1e-12)


@pytest.mark.parametrize(
    ("regions", "obj", "match"),
    [
        (
            [{"select": {"sphere": {"center": [3.0, 3.0, 3.0], "radius": 0.1}}, "density": 5.0}],
            {},
            r"density_regions\[0\]: the selection holds no whole element",
        ),
        ([{"select": {"indices": [10**6]}, "density": 5.0}], {}, r"density_regions\[0\]\.select\.indices"),
        ([{"select": {"box": [[0, 0], [1, 1]]}, "density": 5.0}], {}, r"density_regions\[0\]\.select\.box"),
        ([{"select": {"indices": [0]}, "density": -1.0}], {}, r"density"),
    ],
)
def test_bad_regions_name_the_key(regions, obj, match):
    with pytest.raises(SceneError, match=match):
        build_scene(scene_from_dict(_scene(regions, **obj)))


def test_only_deformables_have_density_regions():
    d = _scene([{"select": {"indices": [0]}, "density": 5.0}])
    d["objects"][0].update(kind="obstacle", material=None)
    del d["objects"][0]["material"]
    with pytest.raises(SceneError, match="density_regions: only for deformable"):
        scene_from_dict(d)
