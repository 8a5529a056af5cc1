"""Sticky contact (opt-in, outside the paper's energy): weak springs between close surface vertices of chosen
bodies pull them into barrier contact without ever crossing; scene errors name the key."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.spatial import cKDTree

from idp.api import simulate
from idp.errors import SceneError
from idp.scene.load import scene_from_dict


def _scene(sticky: dict | None, **over) -> dict[str, Any]:
    """Two soft balls 0.02 apart, no gravity: at rest unless something pulls them together."""
    d: dict[str, Any] = {
        "name": "sticky",
        "dim": 3,
        "time": {"h": 1e-2, "steps": 4},
        "contact": {"dhat": 1e-3},
        "output": {"png": False, "obj": False, "vtu": False},
        "objects": [
            {
                "name": f"ball_{k}",
                "generate": {"shape": "ball", "radius": 0.2, "resolution": 2},
                "translate": [sx * 0.21, 0.0, 0.0],
                "material": {"youngs_modulus": 1e3},
            }
            for k, sx in enumerate((-1.0, 1.0))
        ],
    }
    if sticky is not None:
        d["sticky"] = sticky
    d.update(over)
    return d


def test_links_pull_bodies_into_contact_and_every_frame_is_certified(tmp_path):
    free = simulate(scene_from_dict(_scene(None)), tmp_path / "free", progress=False)
    assert free.summary["min_distance"] == np.inf  # nothing moves them: never within d̂
    res = simulate(
        scene_from_dict(_scene({"bodies": ["ball_*"], "distance": 0.1, "stiffness": 50.0})),
        tmp_path / "sticky",
        progress=False,
    )
    assert res.summary["all_certified"]
    links = [r["sticky"]["links"] for r in res.step_records if "sticky" in r and not r.get("initial")]
    assert len(links) == 4 and min(links) > 0 and links[-1] >= links[0]  # more pairs come close as they pull
    assert 0.0 < res.summary["min_distance"] < 1e-3  # in barrier contact, never touching
    n = res.x.shape[0] // 2
    gap0 = 0.02
    assert res.x[n:, 0].min() - res.x[:n, 0].max() < gap0 / 2  # the balls moved towards each other


def test_links_join_different_bodies_only(tmp_path):
    # one body alone: its own vertices within `distance` of each other are never linked
    d = _scene({"bodies": ["ball_0", "ball_1"], "distance": 0.1})
    d["time"]["steps"] = 1
    res = simulate(scene_from_dict(d), tmp_path / "r", progress=False)
    from idp.scene.build import build_scene

    built = build_scene(scene_from_dict(d))
    sticky = next(c for c in built.system.conditions if getattr(c, "report_key", None) == "sticky")
    sticky.before_step(built.system, 1, built.system.x)
    pairs = sticky.springs.pairs
    n = built.system.x.shape[0] // 2
    assert pairs.shape[0] > 0 and np.all((pairs[:, 0] < n) != (pairs[:, 1] < n))
    assert np.linalg.norm(built.system.x[pairs[:, 0]] - built.system.x[pairs[:, 1]], axis=1).max() <= 0.1
    assert res.summary["all_certified"]


@pytest.mark.parametrize(
    ("sticky", "over", "match"),
    [
        ({"bodies": ["pan*"], "distance": 0.1}, {}, r"sticky\.bodies\[0\].*'pan\*' matches no object"),
        ({"bodies": ["ball_*"], "distance": 0.0}, {}, r"sticky\.distance"),
        ({"bodies": ["ball_*"], "distance": 0.1}, {"contact": {"dhat": 1e-3, "barrier": "ipctk"}}, "compiled"),
    ],
)
def test_bad_sticky_sections_name_the_key(sticky, over, match):
    with pytest.raises(SceneError, match=match):
        scene_from_dict(_scene(sticky, **over))


def test_sticky_is_3d_only():
    d = {
        "name": "flat",
        "dim": 2,
        "objects": [{"name": "disk", "generate": {"shape": "disk", "radius": 0.2, "resolution": 2}}],
        "sticky": {"bodies": ["disk"], "distance": 0.1},
    }
    with pytest.raises(SceneError, match="3D"):
        scene_from_dict(d)


def test_stages_link_only_the_bodies_taking_part(tmp_path):
    from idp.applications.modeling import run_stages

    d = _scene({"bodies": ["ball_*"], "distance": 0.1, "stiffness": 50.0})
    d["stages"] = [{"name": "together", "steps": 1}, {"name": "alone", "steps": 1, "remove": ["ball_1"]}]
    res = run_stages(scene_from_dict(d), tmp_path / "r", progress=False)
    assert res.all_certified
    from idp.scene.load import load_scene

    s0 = load_scene(tmp_path / "r" / "stages" / "00_together" / "scene.resolved.toml")
    s1 = load_scene(tmp_path / "r" / "stages" / "01_alone" / "scene.resolved.toml")
    assert s0.sticky is not None and s0.sticky.bodies == ["ball_0", "ball_1"]
    assert s1.sticky is None  # one body left: nothing to link


def _clam(tmp_path, mode: str, stiffness: float = 50.0, steps: int = 3, pull: float = 0.0) -> dict[str, Any]:
    """One body of two balls 0.01 apart (a closed seam whose lips touch but are not joined), no gravity; with
    ``pull`` the right ball's far cap is moved away at that speed."""
    import meshio

    from idp.mesh.generate import tet_ball

    path = tmp_path / "clam.vtu"
    if not path.exists():
        a, b = tet_ball(0.2, (-0.205, 0.0, 0.0), 3), tet_ball(0.2, (0.205, 0.0, 0.0), 3)
        pts = np.vstack([a.vertices, b.vertices])
        tets = np.vstack([a.elements, b.elements + a.vertices.shape[0]])
        meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    ob: dict[str, Any] = {"name": "clam", "mesh": str(path), "material": {"youngs_modulus": 1e3}}
    if pull:
        ob["handles"] = [
            {
                "name": "pull",
                "select": {"box": [[0.95, -0.01, -0.01], [1.01, 1.01, 1.01]], "relative": True},
                "motion": {"type": "translate", "velocity": [pull, 0.0, 0.0]},
            }
        ]
    return {
        "name": "clam",
        "dim": 3,
        "time": {"h": 1e-2, "steps": steps},
        "contact": {"dhat": 1e-3},
        "output": {"png": False, "obj": False, "vtu": False},
        "objects": [ob],
        "sticky": {"bodies": ["clam"], "distance": 0.05, "stiffness": stiffness, "mode": mode},
    }


def test_glue_links_a_bodys_facing_surfaces_and_not_its_neighbours(tmp_path):
    from idp.scene.build import build_scene

    built = build_scene(scene_from_dict(_clam(tmp_path, "glue")))
    sticky = next(c for c in built.system.conditions if getattr(c, "report_key", None) == "sticky")
    x = built.system.x
    pairs = sticky.candidate_pairs(x)
    n = x.shape[0] // 2
    # every link crosses the seam (left ball to right ball); none joins two vertices of one ball, although
    # surface neighbours of a ball lie within the link radius too
    assert pairs.shape[0] > 0 and np.all((pairs[:, 0] < n) != (pairs[:, 1] < n))
    near = cKDTree(x[sticky.vertices]).query_pairs(0.05, output_type="ndarray")
    tree_pairs = sticky.vertices[near]
    assert np.any((tree_pairs[:, 0] < n) == (tree_pairs[:, 1] < n))  # such neighbour pairs exist and were dropped
    # relinking joins different bodies only: nothing to link within one body (and one body is too few for it)
    relink = build_scene(scene_from_dict(_clam(tmp_path, "relink")))
    assert not any(getattr(c, "report_key", None) == "sticky" for c in relink.system.conditions)


def test_glue_is_made_once_and_holds_a_seam_closed(tmp_path):
    glued = simulate(scene_from_dict(_clam(tmp_path, "glue", pull=0.5)), tmp_path / "glue", progress=False)
    loose = simulate(
        scene_from_dict({**_clam(tmp_path, "glue", pull=0.5), "sticky": None}), tmp_path / "loose", progress=False
    )
    assert glued.summary["all_certified"] and loose.summary["all_certified"]
    recs = [r["sticky"] for r in glued.step_records if "sticky" in r and not r.get("initial")]
    assert len(recs) == 3 and all(r["glued_at"] == 1 for r in recs)
    assert len({r["links"] for r in recs}) == 1 and recs[0]["links"] > 0  # the same links all along
    n = glued.x.shape[0] // 2
    # the right ball is pulled 0.015 away; the glue drags the left ball after it, the loose one stays put
    assert loose.x[:n, 0].max() < -0.005 + 1e-3
    assert glued.x[:n, 0].max() > loose.x[:n, 0].max() + 2e-3
    assert 0.0 < glued.summary["min_distance"]


def test_glue_links_survive_a_resume(tmp_path):
    whole = simulate(scene_from_dict(_clam(tmp_path, "glue", pull=0.5, steps=4)), tmp_path / "whole", progress=False)
    simulate(scene_from_dict(_clam(tmp_path, "glue", pull=0.5, steps=2)), tmp_path / "split", progress=False)
    resumed = simulate(
        scene_from_dict(_clam(tmp_path, "glue", pull=0.5, steps=4)), tmp_path / "split", progress=False, resume=True
    )
    last = [r["sticky"] for r in resumed.step_records if "sticky" in r and not r.get("initial")][-1]
    assert last["glued_at"] == 1  # restored from the checkpoint, not glued again at step 3
    ref = [r["sticky"] for r in whole.step_records if "sticky" in r and not r.get("initial")][-1]
    assert last["links"] == ref["links"]
    np.testing.assert_allclose(resumed.x, whole.x, atol=1e-8)
