"""Min-max distortion (paper §7.4): the p-norm lowers the worst element under the same handles, `idp uv`
improves a stretched UV layout of a generated cut cylinder keeping it injective and the rest of the OBJ intact,
and bad UV input is refused before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from idp.api import simulate
from idp.applications.uv_map import run_uv, uv_scene
from idp.cli import EXIT_INPUT, main
from idp.errors import IntersectingInputError, MeshError
from idp.mesh.uv_obj import cut_cylinder_obj_text, read_uv_obj, uv_overlaps, uv_signed_areas
from idp.scene.load import scene_from_dict


def _disk_push_doc(p: float) -> dict:
    """A small disk pushed inwards at four boundary points (Fig. 19 in miniature)."""
    handles = []
    for name, lo, hi, v in (
        ("left", [0.0, 0.45], [0.05, 0.55], [1.0, 0.0]),
        ("right", [0.95, 0.45], [1.0, 0.55], [-1.0, 0.0]),
        ("bottom", [0.45, 0.0], [0.55, 0.05], [0.0, 1.0]),
        ("top", [0.45, 0.95], [0.55, 1.0], [0.0, -1.0]),
    ):
        handles.append(
            {
                "name": name,
                "select": {"box": [lo, hi], "relative": True},
                "motion": {"type": "translate", "velocity": v},
            }
        )
    return {
        "name": f"disk-p{p:g}",
        "dim": 2,
        "time": {"steps": 6},
        "solver": {"newton_tol": 1e-2},
        "output": {"obj": False, "vtu": False, "png": False, "distortion": True},
        "objects": [
            {
                "name": "disk",
                "generate": {"shape": "disk", "radius": 1.0, "resolution": 6},
                "material": {"model": "symmetric_dirichlet", "youngs_modulus": 2e4, "power": p},
                "handles": handles,
            }
        ],
    }


def test_p10_lowers_the_worst_distortion_of_p1_under_the_same_handles(tmp_path: Path) -> None:
    worst = {}
    for p in (1.0, 10.0):
        res = simulate(scene_from_dict(_disk_push_doc(p)), tmp_path / f"p{p:g}", progress=False)
        steps = [r for r in res.step_records if not r.get("initial")]
        assert res.summary["all_certified"] and all(r["dirichlet"]["met"] for r in steps)
        worst[p] = steps[-1]["distortion"]["worst"]
        assert steps[-1]["distortion"]["mean"] >= 4.0  # Ψ_SD ≥ 4 in 2D, isometries only
    assert worst[10.0] < 0.8 * worst[1.0], worst


def _write_cylinder(path: Path, **kw) -> Path:
    path.write_text(cut_cylinder_obj_text(16, 6, **kw))
    return path


def test_idp_uv_improves_a_stretched_layout_and_keeps_the_rest_of_the_obj(tmp_path: Path) -> None:
    src = _write_cylinder(tmp_path / "cyl.obj", uv_scale=(3.0, 0.4))
    out = tmp_path / "cyl_out.obj"
    assert main(["uv", str(src), "-o", str(out), "-q", "--steps", "60"]) == 0
    report = json.loads((tmp_path / "cyl_out_uv" / "report.json").read_text())
    assert report["before"]["worst"] > 10 and report["after"]["worst"] < 0.5 * report["before"]["worst"]
    assert report["flipped_after"] == 0 and report["overlapping_pairs_after"] == 0
    for name in ("report.md", "distortion.png", "stats.json"):
        assert (tmp_path / "cyl_out_uv" / name).is_file()
    a, b = src.read_text().splitlines(), out.read_text().splitlines()
    assert len(a) == len(b)
    assert [x for x in a if not x.startswith("vt ")] == [y for y in b if not y.startswith("vt ")]
    new = read_uv_obj(out)
    assert np.all(uv_signed_areas(new.uv, new.faces_uv) > 0)
    assert uv_overlaps(new.uv, new.faces_uv).size == 0
    stats = json.loads((tmp_path / "cyl_out_uv" / "stats.json").read_text())
    assert stats["summary"]["all_certified"]


def test_the_paper_stop_rule_ends_after_a_one_iteration_step(tmp_path: Path) -> None:
    src = _write_cylinder(tmp_path / "cyl.obj", uv_scale=(1.3, 0.8))
    res, _ = run_uv(uv_scene(src, p=4.0, steps=500, newton_tol=1e-2), tmp_path / "o.obj", progress=False)
    assert "converged in 1 Newton iteration" in res.summary["stopped"]
    assert res.step_records[-1]["newton_iterations"] <= 1 and res.summary["steps_run"] < 500


def test_a_mirrored_layout_is_handled(tmp_path: Path) -> None:
    text = cut_cylinder_obj_text(16, 6, uv_scale=(2.0, 0.6))
    lines = [f"vt {-float(ln.split()[1])!r} {ln.split()[2]}" if ln.startswith("vt ") else ln for ln in text.split("\n")]
    src = tmp_path / "mirror.obj"
    src.write_text("\n".join(lines))
    _, report = run_uv(uv_scene(src, steps=40), tmp_path / "o.obj", progress=False)
    assert report["mirrored_input"] and report["after"]["worst"] < report["before"]["worst"]
    new = read_uv_obj(tmp_path / "o.obj")
    assert np.all(uv_signed_areas(new.uv, new.faces_uv) < 0)  # still mirrored, as the input, never flipped


def _two_triangles(path: Path, second_offset: float) -> Path:
    path.write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
        f"vt 0 0\nvt 1 0\nvt 0 1\nvt {second_offset} 0.1\nvt {second_offset + 1} 0.1\nvt {second_offset} 1.1\n"
        "f 1/1 2/2 3/3\nf 4/4 5/5 6/6\n"
    )
    return path


def test_overlapping_charts_are_refused_unless_preserved(tmp_path: Path) -> None:
    src = _two_triangles(tmp_path / "overlap.obj", 0.2)
    with pytest.raises(IntersectingInputError, match="overlaps itself"):
        run_uv(uv_scene(src, steps=3), tmp_path / "o.obj", progress=False)
    assert not (tmp_path / "o.obj").exists() and not (tmp_path / "o_uv").exists()
    assert main(["uv", str(src), "-o", str(tmp_path / "o.obj"), "-q"]) == EXIT_INPUT
    # kept as they are, and no new overlap is added
    _, report = run_uv(uv_scene(src, steps=3, preserve_overlaps=True), tmp_path / "p.obj", progress=False)
    assert report["overlapping_pairs_after"] == report["overlapping_pairs_before"] == 1


def test_bad_uv_input_gets_clear_errors_and_writes_nothing(tmp_path: Path) -> None:
    no_vt = tmp_path / "novt.obj"
    no_vt.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="texture coordinates"):
        run_uv(uv_scene(no_vt), tmp_path / "o.obj", progress=False)
    flat = tmp_path / "flat3d.obj"  # a zero-area 3D triangle: no rest metric
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(MeshError, match=r"(?i)area"):
        run_uv(uv_scene(flat), tmp_path / "o.obj", progress=False)
    src = _write_cylinder(tmp_path / "cyl.obj", uv_scale=(2.0, 0.5))
    before = src.read_bytes()
    with pytest.raises(MeshError, match="input file"):
        run_uv(uv_scene(src), src, progress=False)
    assert src.read_bytes() == before
    assert main(["uv", str(src), "-o", str(tmp_path / "o.obj"), "--p", "0.5", "-q"]) == EXIT_INPUT
    assert not (tmp_path / "o.obj").exists()
    with pytest.raises(Exception, match="power"):
        uv_scene(src, p=0.5)


def _iterations_and_alphas(res) -> tuple[int, float, float, bool]:
    steps = [r for r in res.step_records if not r.get("initial")]
    its = sum(r["newton_iterations"] for r in steps)
    largest = max(max(r["alphas"] or [0.0]) for r in steps)
    met = all(r["dirichlet"]["met"] for r in steps)
    return its, largest, steps[-1]["distortion"]["worst"], met


def test_extrapolated_steps_save_iterations_at_p10_and_every_iterate_is_certified(tmp_path: Path) -> None:
    """After a full Newton step the line search doubles it while the energy falls (``line_search_extrapolation``,
    "auto" = 2p for p > 1). Every iterate passes the independent certificate (``check_every_iterate`` raises
    otherwise), and the minimiser is the same: the worst distortion agrees to 1 %."""
    figures = {}
    for setting in (1.0, "auto"):
        doc = _disk_push_doc(10.0)
        doc["solver"].update({"line_search_extrapolation": setting, "check_every_iterate": True})
        res = simulate(scene_from_dict(doc), tmp_path / str(setting), progress=False)
        assert res.summary["all_certified"]
        figures[setting] = _iterations_and_alphas(res)
    its_off, alpha_off, worst_off, met_off = figures[1.0]
    its_on, alpha_on, worst_on, met_on = figures["auto"]
    assert alpha_off <= 1.0 < alpha_on <= 20.0
    assert met_off and met_on
    assert its_on < its_off, figures
    assert worst_on == pytest.approx(worst_off, rel=1e-2)


def test_extrapolated_steps_towards_an_obstacle_stay_certified(tmp_path: Path) -> None:
    """A p = 10 disk dragged by a handle on its left part towards a wall 0.01 away: steps are extended on the way
    (each longer move checked by CCD and the inversion filter like any other), the disk reaches the wall, and every
    iterate passes the independent certificate (``check_every_iterate`` raises otherwise)."""
    doc = _disk_push_doc(10.0)
    doc["solver"].update({"check_every_iterate": True})
    disk = doc["objects"][0]
    disk["handles"] = [h for h in disk["handles"] if h["name"] == "left"]
    disk["handles"][0]["select"]["box"] = [[0.0, 0.0], [0.4, 1.0]]  # the left part: the disk follows it
    wall = {"shape": "box_polygon", "lo": [1.01, -2.0], "hi": [1.5, 2.0]}
    doc["objects"].append({"name": "wall", "kind": "obstacle", "generate": wall})
    res = simulate(scene_from_dict(doc), tmp_path / "wall", progress=False)
    assert res.summary["all_certified"]
    steps = [r for r in res.step_records if not r.get("initial")]
    assert max(r["contacts"] for r in steps) > 0, "the disk never reached the wall"
    assert max(max(r["alphas"] or [0.0]) for r in steps) > 1.0, "no step was extended on the way"
    assert min(min(r["ccd_alphas"] or [1.0]) for r in steps) < 1.0, "CCD never limited a step"
    assert all(r["dirichlet"]["met"] for r in steps)


def test_extrapolation_setting_auto_follows_the_largest_power_and_bad_values_are_refused() -> None:
    from types import SimpleNamespace

    from idp.errors import SceneError
    from idp.solver.newton import line_search_extrapolation

    def terms(*powers):
        return [SimpleNamespace(term=SimpleNamespace(power=p)) for p in powers]

    assert line_search_extrapolation("auto", terms(1.0)) == 1.0
    assert line_search_extrapolation("auto", terms(1.0, 5.0)) == 10.0
    assert line_search_extrapolation("auto", []) == 1.0
    assert line_search_extrapolation("auto", [SimpleNamespace(term=object())]) == 1.0  # terms without a power
    assert line_search_extrapolation(3.0, terms(10.0)) == 3.0
    for bad in (0.5, -1, "fast", float("nan")):
        doc = _disk_push_doc(10.0)
        doc["solver"]["line_search_extrapolation"] = bad
        with pytest.raises(SceneError, match="line_search_extrapolation"):
            scene_from_dict(doc)
