"""Scene schema and loader: defaults, key-path error messages, round trips."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from idp.errors import SceneError
from idp.scene.load import (
    dump_scene_toml,
    load_scene,
    resolved_scene_dict,
    scene_from_dict,
)
from idp.scene.schema import (
    BallGen,
    BoxSurfaceGen,
    DiskGen,
    Material,
    Rotation,
    Scene,
    SceneObject,
)

MINIMAL_TOML = """\
[[objects]]
name = "blob"
kind = "deformable"
generate = { shape = "ball", radius = 0.3 }

[[objects]]
name = "box"
kind = "obstacle"
generate = { shape = "box_surface" }
"""


def minimal() -> dict[str, Any]:
    """The minimal scene as plain data."""
    return {
        "objects": [
            {"name": "blob", "kind": "deformable", "generate": {"shape": "ball", "radius": 0.3}},
            {"name": "box", "kind": "obstacle", "generate": {"shape": "box_surface"}},
        ]
    }


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def check_defaults(scene: Scene, tmp_path: Path) -> None:
    assert scene.dim == 3
    assert scene.time.h == 0.0016 and scene.time.steps == 60
    assert scene.solver.newton_tol == 1e-2 and scene.solver.max_newton_iterations == 200
    assert scene.contact.kappa == "auto" and scene.contact.dhat == 1e-3
    blob, box = scene.objects
    assert isinstance(blob.generate, BallGen) and blob.generate.radius == 0.3
    assert blob.generate.params() == {"radius": 0.3, "center": [0.0, 0.0, 0.0], "resolution": 6}
    assert blob.material == Material(model="neo_hookean", youngs_modulus=1e4, poisson_ratio=0.4, density=1000.0)
    assert blob.rest_shape is not None and blob.rest_shape.scale == 1.0
    assert blob.translate == [0.0, 0.0, 0.0]
    assert isinstance(box.generate, BoxSurfaceGen) and box.generate.lo == [-1.0, -1.0, -1.0]
    assert box.material is None and box.rest_shape is None
    assert scene.output.dir == tmp_path / "out"


def test_minimal_toml_and_json_load_with_defaults(tmp_path: Path) -> None:
    t = load_scene(write(tmp_path, "mini.toml", MINIMAL_TOML))
    j = load_scene(write(tmp_path, "mini.json", json.dumps(minimal())))
    assert t.name == "mini" and j.name == "mini"
    check_defaults(t, tmp_path)
    check_defaults(j, tmp_path)
    assert t == j


def test_unknown_extension(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match=r"extension"):
        load_scene(write(tmp_path, "mini.yaml", MINIMAL_TOML))


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """Mutator setting a dotted/indexed key (e.g. 'objects.0.material') in the scene data."""

    def apply(d: dict[str, Any]) -> None:
        keys: list[Any] = [int(k) if k.isdigit() else k for k in path.split(".")]
        cur: Any = d
        for k in keys[:-1]:
            if isinstance(cur, dict):
                cur = cur.setdefault(k, {})
            else:
                cur = cur[k]
        cur[keys[-1]] = value

    return apply


BAD_CASES = {
    "unknown top-level key": (_set("wind", 9.8), r"scene\.toml: wind: unknown key"),
    "unknown nested key": (
        _set("objects.0.materiall", {"youngs_modulus": 1.0}),
        r"objects\[0\]\.materiall: unknown key \(did you mean 'material'\?\)",
    ),
    "wrong type": (_set("time.steps", "ten"), r"time\.steps: must be an integer \(got \"ten\"\)"),
    "negative dhat": (_set("contact.dhat", -1e-3), r"contact\.dhat: must be > 0"),
    "nu = 0.5": (
        _set("objects.0.material", {"poisson_ratio": 0.5}),
        r"objects\[0\]\.material\.poisson_ratio: must be < 0\.5 \(got 0\.5\).*incompressible",
    ),
    "h zero": (_set("time.h", 0.0), r"time\.h: must be > 0"),
    "h negative": (_set("time.h", -0.01), r"time\.h: must be > 0.*\(got -0\.01\)"),
    "mesh and generate": (_set("objects.0.mesh", "blob.vtk"), r"objects\[0\]\.generate: .*not both"),
    "material on obstacle": (
        _set("objects.1.material", {}),
        r"objects\[1\]\.material: only allowed on deformable",
    ),
    "duplicate names": (_set("objects.1.name", "blob"), r"objects\[1\]\.name: duplicate name 'blob'"),
    "vector length": (_set("objects.0.translate", [1.0, 2.0]), r"objects\[0\]\.translate: must have 3 entries"),
    "2D vector length": (_set("dim", 2), r"objects\[0\]\.generate\.shape: 'ball' is a 3D shape"),
    "growth non-positive": (
        _set("objects.0.rest_shape", {"growth_rate": -0.25, "growth_steps": 4}),
        r"objects\[0\]\.rest_shape\.growth_rate: .*<= 0",
    ),
    "unknown shape": (_set("objects.0.generate.shape", "blobby"), r"objects\[0\]\.generate\.shape: unknown shape"),
    "generator key": (
        _set("objects.0.generate.radiuss", 1.0),
        r"objects\[0\]\.generate\.radiuss: unknown key \(did you mean 'radius'\?\)",
    ),
    "surface shape as deformable": (
        _set("objects.0.generate", {"shape": "box_surface"}),
        r"objects\[0\]\.generate\.shape: 'box_surface' makes a closed surface",
    ),
    "bad literal": (_set("solver.linear_solver", "mkl"), r"solver\.linear_solver: must be one of"),
    "rotation axis zero": (
        _set("objects.0.rotate", [{"axis": [0, 0, 0], "degrees": 10}]),
        r"objects\[0\]\.rotate\[0\]\.axis: must be non-zero",
    ),
    "fixed box inverted": (
        _set("objects.0.fixed", [{"box": [[0, 0, 0], [1, -1, 1]]}]),
        r"objects\[0\]\.fixed\[0\]\.box: need lo <= hi",
    ),
    "no deformable": (
        _set("objects", [{"name": "box", "kind": "obstacle", "generate": {"shape": "box_surface"}}]),
        r"objects: at least one deformable or shell object is required",
    ),
    "kappa": (_set("contact.kappa", -3.0), r"contact\.kappa: must be \"auto\" or a number > 0"),
    "bool type": (_set("output.png", "yes"), r"output\.png: must be true or false"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_errors_name_key_path(tmp_path: Path, case: str) -> None:
    mutate, pattern = BAD_CASES[case]
    data = minimal()
    mutate(data)
    path = write(tmp_path, "scene.toml", dump_plain_toml(data))
    with pytest.raises(SceneError, match=pattern) as info:
        load_scene(path)
    msg = str(info.value)
    assert all(line.startswith(f"{path}: ") for line in msg.splitlines()), msg
    assert "pydantic" not in msg and "Input should" not in msg
    assert info.value.__cause__ is not None  # chained from the pydantic error


def dump_plain_toml(data: dict[str, Any]) -> str:
    """Test helper: write raw (unvalidated) data as TOML via JSON -> TOML inline tables."""

    def val(v: Any) -> str:
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return json.dumps(v)

    return "".join(f"{k} = {val(v)}\n" for k, v in data.items())


def test_missing_mesh_file_names_key_and_path(tmp_path: Path) -> None:
    data = minimal()
    del data["objects"][0]["generate"]
    data["objects"][0]["mesh"] = "meshes/nope.vtk"
    path = write(tmp_path, "scene.json", json.dumps(data))
    with pytest.raises(SceneError, match=r"objects\[0\]\.mesh: file not found: .*meshes/nope\.vtk"):
        load_scene(path)


def test_mesh_path_resolved_relative_to_scene_file(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "blob.vtk").write_text("dummy")
    data = minimal()
    del data["objects"][0]["generate"]
    data["objects"][0]["mesh"] = "meshes/blob.vtk"
    scene = load_scene(write(tmp_path, "scene.json", json.dumps(data)))
    assert scene.objects[0].mesh == tmp_path / "meshes" / "blob.vtk"
    assert scene.objects[0].mesh.is_absolute()


def test_toml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    path = write(tmp_path, "broken.toml", 'name = "x"\ndim = 3\n[time\nh = 1\n')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert str(path) in msg and "line 3" in msg


def test_json_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    path = write(tmp_path, "broken.json", '{\n  "dim": 3,\n  "time": {,}\n}\n')
    with pytest.raises(SceneError, match=r"broken\.json: JSON syntax error.*line 3"):
        load_scene(path)


def test_several_problems_one_line_each() -> None:
    data = minimal()
    data["time"] = {"h": -1.0, "steps": 0}
    data["contact"] = {"dhat": 0}
    with pytest.raises(SceneError) as info:
        scene_from_dict(data)
    lines = str(info.value).splitlines()
    assert len(lines) == 3
    assert {ln.split(": ")[1] for ln in lines} == {"time.h", "time.steps", "contact.dhat"}


def test_python_api_raises_scene_error() -> None:
    with pytest.raises(SceneError, match=r"poisson_ratio: must be < 0\.5"):
        Material(poisson_ratio=0.5)
    with pytest.raises(SceneError, match=r"objects\[0\]\.rotate\[0\]\.axis: must be omitted in 2D"):
        Scene(dim=2, objects=[SceneObject(name="d", generate=DiskGen(), rotate=[Rotation(axis=[0, 0, 1], degrees=5)])])
    scene = Scene(dim=2, objects=[SceneObject(name="d", generate=DiskGen(), rotate=[Rotation(degrees=5)])])
    assert scene.objects[0].translate == [0.0, 0.0]


def test_symmetric_dirichlet_weight_default() -> None:
    m = Material(model="symmetric_dirichlet", youngs_modulus=3.0, poisson_ratio=0.0)
    assert m.weight == pytest.approx(3.0 / 2.0 / 4.0)


def _rich_scene(tmp_path: Path) -> Scene:
    (tmp_path / "bunny.vtk").write_text("dummy")
    text = """\
name = "rich"
dim = 3
[time]
h = 0.0016
steps = 5
stop_when_stationary = true
[contact]
kappa = 1e5
dhat_mode = "relative"
[[objects]]
name = "bunny"
mesh = "bunny.vtk"
scale = [1.0, 2.0, 3.0]
rotate = [{axis = [1, 0, 0], degrees = -90}, {axis = [0, 1, 0], degrees = 45}]
translate = [0.1, 0.2, 0.3]
material = { model = "symmetric_dirichlet", youngs_modulus = 2e4 }
rest_shape = { scale = [1.1, 3.2, 1.1], growth_rate = 0.5, growth_steps = 10 }
fixed = [{ box = [[0, 0, 0], [1, 0.1, 1]], relative = true }, { indices = [0, 5, 9] }]
[[objects]]
name = "cage"
kind = "obstacle"
generate = { shape = "hourglass_surface", rings = 20 }
"""
    return load_scene(write(tmp_path, "rich.toml", text))


def test_resolved_dict_round_trip(tmp_path: Path) -> None:
    scene = _rich_scene(tmp_path)
    d = resolved_scene_dict(scene)
    assert json.loads(json.dumps(d)) == d
    assert d["objects"][0]["material"]["weight"] == pytest.approx(2e4 / 2.8 / 4)
    again = scene_from_dict(copy.deepcopy(d))
    assert again == scene
    assert again is not scene


def test_dump_toml_reloads_equal(tmp_path: Path) -> None:
    scene = _rich_scene(tmp_path)
    text = dump_scene_toml(scene)
    other = tmp_path / "elsewhere"
    other.mkdir()
    again = load_scene(write(other, "resolved.toml", text))
    assert again == scene
    scene.time.steps = 6
    assert again != scene


def test_dump_toml_minimal_round_trip(tmp_path: Path) -> None:
    scene = load_scene(write(tmp_path, "mini.toml", MINIMAL_TOML))
    again = load_scene(write(tmp_path, "again.toml", dump_scene_toml(scene)))
    assert again == scene and again.name == "mini"


def test_a_key_ending_in_a_line_break_is_quoted_in_error_paths():
    # found by tests/fuzz: `re.match("^...$")` accepts "0\n" (``$`` matches before a final newline), so the key was
    # printed bare and the error broke over two lines without naming the source on the second
    from idp.scene.load import scene_from_dict

    with pytest.raises(SceneError) as err:
        scene_from_dict({"objects": [{"generate": {"shape": "ball"}, "fixed": [{"0\n": None}]}]}, source="s.toml")
    lines = str(err.value).splitlines()
    assert all(line.startswith("s.toml: ") for line in lines) and '"0\\n"' in str(err.value)


def test_paths_of_objects_a_stage_adds_resolve_against_the_scene_file(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "cap.vtk").write_text("dummy")
    data = minimal()
    data["stages"] = [
        {"name": "a", "steps": 1},
        {"name": "b", "steps": 1, "add": [{"name": "cap", "mesh": "meshes/cap.vtk", "rest_state": "cap.npz"}]},
    ]
    path = write(tmp_path, "scene.json", json.dumps(data))
    # the rest state is missing: named with its stage and key, as an absolute path next to the scene file
    with pytest.raises(SceneError, match=r"stages\[1\]\.add\[0\]\.rest_state: file not found: .*/cap\.npz") as info:
        load_scene(path)
    assert "mesh" not in str(info.value)
    (tmp_path / "cap.npz").write_text("dummy")
    scene = load_scene(path)
    added = scene.stages[1].add[0]
    assert added.mesh == tmp_path / "meshes" / "cap.vtk" and added.rest_state == tmp_path / "cap.npz"
