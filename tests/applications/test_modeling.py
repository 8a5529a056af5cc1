"""Multi-stage modeling scenes (paper §4.5 bake, §7.5): stage hand-over, bake, carry, resume, gravity, errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from idp.applications.modeling import run_stages
from idp.errors import IntersectingInputError, SceneError
from idp.mesh.io import read_mesh
from idp.scene.build import build_scene
from idp.scene.load import load_scene
from idp.scene.schema import Scene


def _scene(**over) -> Scene:
    """A small plastic ball squeezed by a hanging weight of gravity onto a floor, then relaxed (two stages)."""
    d: dict[str, Any] = {
        "name": "two",
        "dim": 3,
        "gravity": [0.0, -9.8, 0.0],
        "contact": {"dhat": 1e-3},
        "output": {"png": False, "obj": False},
        "objects": [
            {
                "name": "dough",
                "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
                "translate": [0.0, 0.32, 0.0],
                "material": {"youngs_modulus": 2e3},
                "plasticity": {"yield_stress": 50.0},
            },
            {
                "name": "floor",
                "kind": "obstacle",
                "generate": {"shape": "box_surface", "lo": [-1, -0.1, -1], "hi": [1, 0.0, 1], "resolution": 2},
            },
        ],
        "stages": [
            {"name": "drop", "steps": 3, "after": {"dough": "carry"}},
            {"name": "settle", "steps": 2, "set": {"dough": {"material": {"youngs_modulus": 3e3}}}},
        ],
    }
    d.update(over)
    return Scene(**d)


def _final(out: Path, name: str = "dough") -> np.ndarray:
    return read_mesh(out / "final" / f"{name}.vtu", kind="volume").vertices


def test_two_stages_equal_two_runs_with_a_resume_between(tmp_path):
    whole = run_stages(_scene(), tmp_path / "whole", progress=False)
    assert whole.summary["stages_run"] == 2 and whole.all_certified
    part = run_stages(_scene(), tmp_path / "split", progress=False, stop_after=0)
    assert part.summary["stages_run"] == 1 and not (tmp_path / "split" / "final").exists()
    rest = run_stages(_scene(), tmp_path / "split", progress=False, resume=True)
    assert rest.summary["stages_run"] == 2
    # the resumed run took stage 0 from disk; the same arithmetic then follows, up to round-off of the
    # linear solver's thread scheduling (positions ~0.3, d̂ = 1e-3)
    np.testing.assert_allclose(_final(tmp_path / "split"), _final(tmp_path / "whole"), rtol=0, atol=1e-9)
    # the material set by stage 1 is in its resolved scene; stage 0 kept the top-level one
    s0 = load_scene(tmp_path / "whole" / "stages" / "00_drop" / "scene.resolved.toml")
    s1 = load_scene(tmp_path / "whole" / "stages" / "01_settle" / "scene.resolved.toml")
    assert s0.objects[0].material.youngs_modulus == 2e3 and s1.objects[0].material.youngs_modulus == 3e3
    per = json.loads((tmp_path / "whole" / "stages.json").read_text())["per_stage"]
    assert [p["steps"] for p in per] == [3, 2]


def _end_gradient(stage_dir: Path, scene: Scene) -> np.ndarray:
    """The elastic gradient of stage 0's last state with stage 0's own rest frames (rebuilt and resumed)."""
    s = load_scene(stage_dir / "scene.resolved.toml")
    built = build_scene(s)
    from idp.stepper.run import _load_condition_states, _read_checkpoint

    ck = _read_checkpoint(stage_dir / "checkpoint.npz")
    _load_condition_states(ck, built.system, stage_dir / "checkpoint.npz")
    body = built.system.bodies[0]
    return body.elastic.gradient(ck["x"])[: 3 * body.vertex_ids.size]


@pytest.mark.parametrize("after", ["bake", "carry"])
def test_bake_makes_the_shape_stress_free_and_carry_keeps_the_stress(tmp_path, after):
    sc = _scene(stages=[{"name": "drop", "steps": 3, "after": {"dough": after}}, {"name": "next", "steps": 1}])
    run_stages(sc, tmp_path, progress=False, stop_after=0)
    start = run_stages(sc, tmp_path, progress=False, resume=True, stop_after=0)  # done stage: nothing re-run
    assert start.summary["stages_run"] == 1
    g_end = _end_gradient(tmp_path / "stages" / "00_drop", sc)
    # stage 1 as a scene of its own starts from the files stage 0 wrote
    stage1 = Scene.model_validate(
        {
            **sc.model_dump(exclude_none=True, exclude={"stages", "objects"}),
            "objects": [
                {
                    "name": "dough",
                    "mesh": tmp_path / "stages" / "00_drop" / "state" / "dough.vtu",
                    "rest_state": tmp_path / "stages" / "00_drop" / "state" / "dough.rest.npz",
                    "material": {"youngs_modulus": 2e3},
                },
                sc.objects[1].model_dump(exclude_none=True),
            ],
        }
    )
    built = build_scene(stage1)
    body = built.system.bodies[0]
    g = body.elastic.gradient(built.system.x)[: 3 * body.vertex_ids.size]
    scale = np.abs(g_end).max()
    assert scale > 1e-6  # the drop deformed the dough: there is stress to bake away
    if after == "bake":
        assert np.abs(g).max() <= 1e-9 * scale + 1e-12
    else:
        np.testing.assert_allclose(g, g_end, rtol=0, atol=1e-8 * scale)


def test_gravity_moves_a_free_body_by_h_g_per_step(tmp_path):
    sc = Scene.model_validate(
        {
            "dim": 3,
            "gravity": [0.0, -2.0, 0.0],
            "time": {"h": 1e-3, "steps": 3},
            "output": {"png": False, "obj": False, "vtu": False},
            "objects": [{"name": "b", "generate": {"shape": "ball", "radius": 0.2, "resolution": 2}}],
            "solver": {"newton_tol": 1e-9},
        }
    )
    built = build_scene(sc)
    x0 = built.system.x.copy()
    from idp.api import run_built

    res = run_built(sc, built, tmp_path, progress=False)
    np.testing.assert_allclose(res.x - x0, np.tile([0.0, -2.0 * 1e-3 * 3, 0.0], (x0.shape[0], 1)), atol=1e-9)


def test_stage_errors_name_the_stage_and_key():
    with pytest.raises(SceneError, match=r"stages\[1\]\.set\.ghost"):
        _scene(stages=[{"name": "a", "steps": 1}, {"name": "b", "steps": 1, "set": {"ghost": {}}}])
    with pytest.raises(SceneError, match=r"stages\[0\]\.after\.floor"):
        _scene(stages=[{"name": "a", "steps": 1, "after": {"floor": "bake"}}])
    with pytest.raises(SceneError, match=r"stages\[1\]\.name"):
        _scene(stages=[{"name": "a", "steps": 1}, {"name": "a", "steps": 1}])
    with pytest.raises(SceneError, match=r"stages\[1\]\.set\.dough"):  # removed before stage 1
        _scene(stages=[{"name": "a", "steps": 1}, {"name": "b", "steps": 1, "remove": ["dough"], "set": {"dough": {}}}])
    with pytest.raises(SceneError, match=r"stages\[0\]\.set\.floor\.material"):
        _scene(stages=[{"name": "a", "steps": 1, "set": {"floor": {"material": {"youngs_modulus": 1.0}}}}])


def test_a_failing_stage_leaves_the_earlier_ones_intact_and_names_itself(tmp_path):
    bad = {  # added across the dough's top: the stage's input intersects
        "name": "intruder",
        "generate": {"shape": "ball", "radius": 0.05, "resolution": 1},
    }
    sc = _scene(
        stages=[
            {"name": "drop", "steps": 2},
            {
                "name": "add",
                "steps": 1,
                "add": [bad],
                "anchor": {"intruder": {"object": "dough", "at": [0.5, 1.0, 0.5]}},
            },
        ]
    )
    with pytest.raises(IntersectingInputError, match=r"stages\[1\] \(add\)"):
        run_stages(sc, tmp_path, progress=False)
    # wholly inside the dough: no surface crosses, the winding number of its vertex tells
    sc = sc.model_copy(deep=True)
    sc.stages[1].anchor["intruder"].at = [0.5, 0.5, 0.5]
    with pytest.raises(IntersectingInputError, match=r"stages\[1\] \(add\).*intruder inside dough"):
        run_stages(sc, tmp_path / "nested", progress=False)
    done = json.loads((tmp_path / "stages" / "00_drop" / "stage.json").read_text())
    assert done["status"] == "done" and Path(done["objects"]["dough"]["mesh"]).is_file()


def test_an_added_object_is_placed_relative_to_a_current_shape(tmp_path):
    top = {"name": "cap", "generate": {"shape": "ball", "radius": 0.05, "resolution": 1}, "translate": [0, 0.06, 0]}
    sc = _scene(
        stages=[
            {"name": "drop", "steps": 2},
            {"name": "cap", "steps": 1, "add": [top], "anchor": {"cap": {"object": "dough", "at": [0.5, 1.0, 0.5]}}},
        ]
    )
    res = run_stages(sc, tmp_path, progress=False)
    dough = read_mesh(tmp_path / "stages" / "00_drop" / "state" / "dough.vtu", kind="volume").vertices
    cap_in = load_scene(tmp_path / "stages" / "01_cap" / "scene.resolved.toml").object("cap")
    lo, hi = dough.min(axis=0), dough.max(axis=0)
    want = lo + np.array([0.5, 1.0, 0.5]) * (hi - lo) + np.array([0, 0.06, 0])
    np.testing.assert_allclose(cap_in.translate, want, atol=1e-12)
    assert res.all_certified and "cap" in res.final_shapes


@pytest.mark.parametrize("after", ["remesh", "bake_remesh"])
def test_remesh_between_stages_keeps_the_surface_and_transfers_the_rest_state(tmp_path, after):
    pytest.importorskip("tetgen", reason="remeshing needs the optional mesher (pip install idp[remesh])")
    sc = _scene(stages=[{"name": "drop", "steps": 3, "after": {"dough": after}}, {"name": "next", "steps": 1}])
    res = run_stages(sc, tmp_path, progress=False)
    assert res.all_certified
    s0 = tmp_path / "stages" / "00_drop"
    rec = json.loads((s0 / "stage.json").read_text())["objects"]["dough"]
    assert rec["remesh"]["elements_after"] == rec["elements"] > 0
    assert rec["remesh"]["quality_after"]["min_dihedral"] > 0
    # the boundary surface after the remesh is the one the stage ended with (bitwise: points and triangles)
    from idp.mesh.surface import boundary_faces

    built = build_scene(load_scene(s0 / "scene.resolved.toml"))
    from idp.stepper.run import _read_checkpoint

    x_end = _read_checkpoint(s0 / "checkpoint.npz")["x"]
    part = built.system.parts[0]
    old_tris = {tuple(sorted(map(tuple, x_end[f]))) for f in part.surface}
    new = read_mesh(s0 / "state" / "dough.vtu", kind="volume")
    new_tris = {tuple(sorted(map(tuple, new.vertices[f]))) for f in boundary_faces(new.elements)}
    assert new_tris == old_tris
    # the next stage starts with the transferred rest state: stress-free after bake_remesh; with remesh, the
    # deformation gradients of the new elements are the old ones at their centroids (piecewise constant)
    nxt = build_scene(load_scene(tmp_path / "stages" / "01_next" / "scene.resolved.toml"))
    body = nxt.system.bodies[0]
    g = body.elastic.gradient(nxt.system.x)
    if after == "bake_remesh":
        assert np.abs(g).max() < 1e-9
    else:
        F_new = body.elastic.deformation_gradients(nxt.system.x)
        assert np.abs(F_new - np.eye(3)).max() > 1e-3  # the stage's deformation was carried over


def test_remesh_without_the_mesher_names_the_extra(tmp_path, monkeypatch):
    import idp.mesh.remesh as remesh

    monkeypatch.setattr(remesh, "mesher_available", lambda: False)
    sc = _scene(stages=[{"name": "drop", "steps": 1, "after": {"dough": "remesh"}}])
    with pytest.raises(SceneError, match=r"stages\[0\] \(drop\)\.after\.dough.*idp\[remesh\]"):
        run_stages(sc, tmp_path, progress=False)
    assert not (tmp_path / "stages").exists()  # refused before any stage ran
    sc = _scene(
        stages=[{"name": "drop", "steps": 1, "after": {"dough": "remesh"}, "remesh": {"if_unavailable": "skip"}}]
    )
    res = run_stages(sc, tmp_path / "skip", progress=False)
    rec = res.stages[0]["objects"]["dough"]
    assert "skipped" in rec["remesh"]


def test_final_folder_holds_only_the_objects_left_and_a_final_render(tmp_path):
    # a first run whose last stage still has the floor; then the scene gains a stage that removes it
    run_stages(_scene(output={"png": True, "obj": False}), tmp_path / "r", progress=False)
    assert (tmp_path / "r" / "final" / "floor.vtu").exists()
    stages = [
        {"name": "drop", "steps": 3, "after": {"dough": "carry"}},
        {"name": "settle", "steps": 2, "set": {"dough": {"material": {"youngs_modulus": 3e3}}}},
        {"name": "alone", "steps": 1, "remove": ["floor"], "gravity": [0.0, 0.0, 0.0]},
    ]
    res = run_stages(  # an appended stage is no change to the finished ones: no force needed
        _scene(output={"png": True, "obj": False}, stages=stages), tmp_path / "r", progress=False, resume=True
    )
    assert sorted(p.name for p in (tmp_path / "r" / "final").glob("*.vtu")) == ["dough.vtu"]
    assert set(res.final_shapes) == {"dough"}
    import matplotlib.image as mpimg

    img = mpimg.imread(tmp_path / "r" / "final" / "final.png")
    assert img.shape[:2] == (500, 1500) and img[..., :3].var() > 1e-4


def test_final_render_leaves_out_a_body_shut_inside_another():
    from idp.applications.modeling import _visible_parts
    from idp.mesh import generate as gen
    from idp.mesh.surface import boundary_faces
    from idp.output.parts import Part

    outer, inner = gen.tet_ball(radius=1.0, resolution=3), gen.tet_ball(radius=0.5, resolution=2)
    n = outer.vertices.shape[0]
    # a wrapper with a cavity (its inner boundary reversed) around a filling in that cavity, and a ball beside them
    wrapper_surface = np.vstack([boundary_faces(outer.elements), boundary_faces(inner.elements)[:, ::-1] + n])
    filling = inner.vertices * 0.9
    beside = inner.vertices + np.array([3.0, 0.0, 0.0])
    x = np.vstack([outer.vertices, inner.vertices, filling, beside])
    m = inner.vertices.shape[0]
    parts = [
        Part("wrapper", "deformable", np.arange(n + m), outer.elements, wrapper_surface),
        Part(
            "filling",
            "deformable",
            np.arange(n + m, n + 2 * m),
            inner.elements + n + m,
            boundary_faces(inner.elements) + n + m,
        ),
        Part(
            "beside",
            "deformable",
            np.arange(n + 2 * m, n + 3 * m),
            inner.elements + n + 2 * m,
            boundary_faces(inner.elements) + n + 2 * m,
        ),
    ]
    assert [p.name for p in _visible_parts(parts, x)] == ["wrapper", "beside"]


def test_stop_after_by_name_from_the_cli_then_resume(tmp_path, capsys):
    from idp.cli import main
    from idp.scene.load import dump_scene_toml

    path = tmp_path / "two.toml"
    path.write_text(dump_scene_toml(_scene()))
    out = tmp_path / "out"
    assert main(["run", str(path), "-o", str(out), "-q", "--stop-after", "drop"]) == 0
    assert (out / "stages" / "00_drop" / "stage.json").exists() and not (out / "stages" / "01_settle").exists()
    assert main(["run", str(path), "-o", str(out), "-q", "--resume"]) == 0
    per = json.loads((out / "stages.json").read_text())["per_stage"]
    assert [p["stage"] for p in per] == ["drop", "settle"] and [p["steps"] for p in per] == [3, 2]


def test_stop_after_names_an_unknown_stage_or_a_scene_without_stages(tmp_path):
    from idp.api import simulate

    with pytest.raises(SceneError, match=r"no stage named 'fold'; the stages are 0 \(drop\), 1 \(settle\)"):
        run_stages(_scene(), tmp_path / "a", progress=False, stop_after="fold")
    with pytest.raises(SceneError, match=r"stage index 2 is out of range"):
        run_stages(_scene(), tmp_path / "b", progress=False, stop_after=2)
    flat = _scene(stages=[])
    with pytest.raises(SceneError, match="has no `stages`"):
        simulate(flat, tmp_path / "c", progress=False, stop_after=0)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()  # refused before writing
