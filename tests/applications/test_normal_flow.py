"""Normal flow on shells (paper §7.2): positive and negative flows and inflated text stay intersection-free at
every Newton iterate, do what the flow says (volumes grow / shrink, letters bulge), and bad input is refused
before any output is written."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import meshio
import numpy as np
import pytest

from idp.api import simulate
from idp.cli import main
from idp.errors import IntersectingInputError, SceneError
from idp.mesh.generate import ellipsoid_surface, tri_disk
from idp.mesh.surface import enclosed_volume
from idp.scene.load import scene_from_dict


def _stats(out: Path) -> dict:
    return json.loads((out / "stats.json").read_text())


def _sphere(name: str, center, radius=0.2, subdivisions=2) -> dict:
    return {
        "name": name,
        "kind": "shell",
        "generate": {
            "shape": "ellipsoid_surface",
            "radii": [radius] * 3,
            "center": list(center),
            "subdivisions": subdivisions,
        },
    }


def _flow_doc(objects: list[dict], beta: float, steps: int, gamma: float = 0.2, **contact) -> dict:
    return {
        "name": "flow_test",
        "dim": 3,
        "time": {"h": 1.0, "steps": steps},
        "solver": {"newton_tol": 0.02 * abs(beta), "newton_norm": "rms", "check_every_iterate": True},
        "contact": {"dhat": 1e-3, **contact},
        "flow": {"beta": beta, "gamma": gamma},
        "objects": objects,
    }


def _all_certified(stats: dict) -> bool:
    return all(s["certificate"]["ok"] for s in stats["steps"])


def test_two_inflating_spheres_press_into_contact_without_crossing(tmp_path):
    gap = 0.02
    doc = _flow_doc([_sphere("a", (-0.2 - gap / 2, 0, 0)), _sphere("b", (0.2 + gap / 2, 0, 0))], beta=0.01, steps=6)
    res = simulate(scene_from_dict(doc), tmp_path, progress=False)
    stats = _stats(tmp_path)
    assert _all_certified(stats) and res.summary["all_certified"]
    # unobstructed, each sphere would grow its radius by about 6 x 0.01 and the two would overlap by ~0.1
    n = res.x.shape[0] // 2
    a, b = res.x[:n], res.x[n:]
    assert a[:, 0].max() < b[:, 0].min() + 1e-3  # still apart along x (touching, not crossed)
    assert b[:, 0].min() - a[:, 0].max() < gap / 4  # ...but pressed together
    assert stats["summary"]["min_distance"] > 0
    ratios = stats["steps"][-1]["flow"]["volume_ratio"]
    assert ratios > 1.5


def test_negative_flow_on_a_dumbbell_shrinks_it_certified_every_iterate(tmp_path):
    obj = {
        "name": "dumbbell",
        "kind": "shell",
        "generate": {
            "shape": "hourglass_surface",
            "bulb_radius": 0.3,
            "neck_radius": 0.1,
            "upper_center": 0.9,
            "segments": 16,
            "rings": 24,
        },
    }
    res = simulate(scene_from_dict(_flow_doc([obj], beta=-0.01, steps=5)), tmp_path, progress=False)
    stats = _stats(tmp_path)
    assert _all_certified(stats) and res.summary["all_certified"]
    vols = [s["flow"]["volume"] for s in stats["steps"]]
    assert all(v1 < v0 for v0, v1 in itertools.pairwise(vols))
    assert vols[-1] < 0.85 * vols[0]


def _write_disk(path: Path) -> np.ndarray:
    disk = tri_disk(radius=0.2, resolution=6)
    v = np.column_stack([disk.vertices, np.zeros(len(disk.vertices))])
    meshio.write(str(path), meshio.Mesh(v, [("triangle", disk.elements)]), file_format="obj")
    return v


def test_open_disk_with_fixed_outline_bulges_up(tmp_path):
    mesh = tmp_path / "disk.obj"
    v0 = _write_disk(mesh)
    out = tmp_path / "out"
    assert main(["flow", str(mesh), "--beta", "0.01", "--steps", "3", "-o", str(out), "-q"]) == 0
    stats = _stats(out)
    assert _all_certified(stats)
    x = meshio.read(str(out / "obj" / "frame_00003.obj")).points
    r = np.linalg.norm(v0[:, :2], axis=1)
    outline = r > 0.2 - 1e-9
    assert outline.sum() >= 6
    assert np.allclose(x[outline], v0[outline], atol=1e-12)  # pinned where they were
    assert x[~outline, 2].min() > 0  # every interior vertex moved up (+z normals)
    assert x[np.argmin(r), 2] > 0.015  # the centre rose by more than half the unobstructed 3 x 0.01


def test_font_command_inflates_text_certified(tmp_path):
    out = tmp_path / "font"
    assert main(["font", "ok", "--steps", "2", "--height", "0.2", "-o", str(out), "-q"]) == 0
    stats = _stats(out)
    assert _all_certified(stats)
    flat = meshio.read(str(out / "text.obj")).points
    x = meshio.read(str(out / "obj" / "frame_00002.obj")).points
    assert np.allclose(flat[:, 2], 0.0)
    assert x[:, 2].min() >= -1e-12 and x[:, 2].max() > 0.005


@pytest.mark.parametrize(
    ("faces", "message"),
    [
        ([[0, 1, 2], [0, 1, 3], [0, 1, 4]], "non-manifold"),  # three faces on edge (0, 1)
        ([[0, 1, 2], [0, 1, 3]], "winding"),  # edge (0, 1) run the same way by both faces
    ],
)
def test_bad_shell_meshes_are_refused_before_any_output(tmp_path, capsys, faces, message):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0.1], [0, 0.5, 1.0]], dtype=float)
    mesh = tmp_path / "bad.obj"
    meshio.write(str(mesh), meshio.Mesh(v, [("triangle", np.array(faces))]), file_format="obj")
    out = tmp_path / "out"
    assert main(["flow", str(mesh), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err and "bad.obj" in err
    assert not out.exists()


def test_font_errors_are_clear_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "font"
    assert main(["font", "  ", "-o", str(out), "-q"]) == 2
    assert "empty" in capsys.readouterr().err
    assert main(["font", "ok", "--font", str(tmp_path / "missing.ttf"), "-o", str(out), "-q"]) == 2
    assert "missing.ttf" in capsys.readouterr().err
    assert not out.exists()


def test_intersecting_shells_are_refused_or_preserved(tmp_path):
    objects = [_sphere("a", (-0.1, 0, 0)), _sphere("b", (0.13, 0.01, 0.02))]  # overlapping spheres cross
    with pytest.raises(IntersectingInputError, match="intersecting"):
        simulate(scene_from_dict(_flow_doc(objects, beta=0.005, steps=1)), tmp_path / "refused", progress=False)
    assert not (tmp_path / "refused").exists()
    doc = _flow_doc(objects, beta=0.005, steps=2, preserve_input_intersections=True)
    res = simulate(scene_from_dict(doc), tmp_path / "kept", progress=False)
    stats = _stats(tmp_path / "kept")
    assert _all_certified(stats) and res.summary["all_certified"]
    first = stats["steps"][0]["certificate"]["preserved_pairs"]
    assert first > 0 and all(s["certificate"]["intersecting_pairs"] <= first for s in stats["steps"])


@pytest.mark.parametrize("bending_hessian", ["projected", "gauss_newton"])
def test_elastic_shell_pushed_by_a_handle_stays_injective(tmp_path, bending_hessian):
    """Membrane + bending (§4.4): a sphere's top cap pushed down by a handle towards its pinned bottom (with
    either Newton Hessian of the bending)."""
    obj = _sphere("ball", (0, 0, 0), radius=0.2)
    obj["shell"] = {
        "youngs_modulus": 1e4,
        "poisson_ratio": 0.3,
        "thickness": 0.01,
        "density": 100.0,
        "bending_hessian": bending_hessian,
    }
    obj["fixed"] = [{"box": [[0, 0, 0], [1, 0.1, 1]], "relative": True}]
    obj["handles"] = [
        {
            "name": "top",
            "select": {"box": [[0, 0.9, 0], [1, 1, 1]], "relative": True},
            "motion": {"type": "translate", "velocity": [0, -0.06, 0]},
        }
    ]
    doc = {
        "name": "pushed_shell",
        "dim": 3,
        "time": {"h": 0.01, "steps": 4},
        "solver": {"newton_tol": 1e-3, "check_every_iterate": True},
        "contact": {"dhat": 1e-3},
        "objects": [obj],
    }
    res = simulate(scene_from_dict(doc), tmp_path, progress=False)
    stats = _stats(tmp_path)
    assert _all_certified(stats) and res.summary["all_certified"]
    x0 = ellipsoid_surface(radii=(0.2, 0.2, 0.2), subdivisions=2).vertices
    top = x0[:, 1] > x0[:, 1].max() - 0.1 * 0.4
    assert np.allclose(res.x[top, 1] - x0[top, 1], -0.06 * 4 * 0.1, atol=2e-3)  # 4 steps of √h = 0.1 s
    assert res.summary["steps_with_unmet_targets"] == 0
    assert enclosed_volume(res.x, ellipsoid_surface(radii=(0.2,) * 3, subdivisions=2).faces) > 0


def test_unknown_bending_hessian_is_named():
    obj = _sphere("ball", (0, 0, 0), radius=0.2)
    obj["shell"] = {"bending_hessian": "exact"}
    with pytest.raises(SceneError, match="bending_hessian"):
        scene_from_dict({"name": "s", "dim": 3, "objects": [obj]})


@pytest.mark.parametrize("other", ["volume", "obstacle"])
def test_shell_flows_into_a_volume_or_an_obstacle_without_crossing(tmp_path, other):
    """Shell–volume contact (a skin shrinking onto a tet ball) and shell–obstacle contact (a skin inflating in a
    box), certified at every iterate."""
    if other == "volume":
        objects = [
            _sphere("skin", (0, 0, 0), radius=0.15),
            {"name": "core", "generate": {"shape": "ball", "radius": 0.1, "resolution": 2}},
        ]
        beta = -0.02
    else:
        box = {"shape": "box_surface", "lo": [-0.33] * 3, "hi": [0.33] * 3}
        objects = [_sphere("skin", (0, 0, 0), radius=0.3), {"name": "box", "kind": "obstacle", "generate": box}]
        beta = 0.02
    res = simulate(scene_from_dict(_flow_doc(objects, beta=beta, steps=3)), tmp_path, progress=False)
    stats = _stats(tmp_path)
    assert _all_certified(stats) and res.summary["all_certified"]
    assert max(s["contacts"] for s in stats["steps"][1:]) > 0  # they did meet
    skin = res.x[: res.parts[0].vertex_ids.size]
    ratio = stats["steps"][-1]["flow"]["volume_ratio"]
    if other == "volume":
        assert ratio < 1.0  # the skin shrank (onto the ball, which stopped it: contacts above)
    else:
        assert ratio > 1.0 and np.abs(skin).max() < 0.33  # grew, and stayed inside the box
