"""Fuzzing the scene parser: ``idp.scene.load.scene_from_dict`` and ``load_scene`` (TOML and JSON).

Properties:

* a document built by walking the pydantic models of ``idp.scene.schema.MODELS`` (every key, with values of the
  right type, the wrong type, out of range, unknown keys, huge lists) validates to a ``Scene`` or raises
  ``SceneError``; every line of the message is ``SOURCE: KEY.PATH: message`` and the key path leads into the
  document (its parent key exists there);
* the same for one random change of a valid scene, and for text mutations of the committed scenes (then the
  message starts with the file name);
* every scalar key is strict, as the README promises: a number or boolean given as a string (``"1"``,
  ``"true"``) is refused, never coerced;
* loading never writes a file (mesh paths with ``..``, absolute paths, ``data:``, ``~`` and an ``output.dir``
  elsewhere are only resolved and checked for existence).
"""

from __future__ import annotations

import json
import math
import re
import sys
import tempfile
import types
import typing
from pathlib import Path
from typing import Any

import pytest
from fuzz.common import fuzz, mutated_bytes, tree
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from idp.errors import SceneError
from idp.scene.load import load_scene, scene_from_dict
from idp.scene.schema import MODELS, Scene

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENES = sorted((Path(__file__).parents[2] / "idp" / "scenes").rglob("*.toml"))

# mesh paths a hostile scene might name: none may cause a write, all are only resolved and checked
PATHS = [
    "../../../../etc/passwd",
    "/etc/passwd",
    "/dev/zero",
    "/proc/self/mem",
    "data:../../../../etc/passwd",
    "data:",
    "data:/etc/passwd",
    "~/.ssh/id_rsa",
    "~nosuchuser/m.obj",
    "",
    ".",
    "..",
    "/",
    "a\x00b.obj",
    "con.obj",
    "x" * 5000 + ".obj",
    "frames/*.obj",
    "[",
    "file:///etc/passwd",
    "http://example.com/m.obj",
    "$(touch pwned).obj",
    "`touch pwned`.vtk",
]

# ---------------------------------------------------------------------------------------------------- values

JSON_SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)
JUNK = st.recursive(
    JSON_SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8,
)
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1, 0.5, -0.5, 1e-300, 1e300, 2**63, -(2**63), 10**30, 0.0, -0.0]),
    st.integers(min_value=-(10**6), max_value=10**6),
)
KEY = st.one_of(st.text(max_size=12), st.sampled_from(["shape", "type", "name", "mesh", "__class__", "a.b", "x[0]"]))


def _unwrap(tp: Any) -> Any:
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _members(tp: Any) -> list[Any]:
    """The alternatives of a union (``X | Y``, Optional), else [tp]."""
    tp = _unwrap(tp)
    if typing.get_origin(tp) in (typing.Union, getattr(types, "UnionType", typing.Union)):
        return [_unwrap(a) for a in typing.get_args(tp)]
    return [tp]


def value_for(draw: st.DrawFn, tp: Any, depth: int) -> Any:
    """A value for annotation ``tp``: usually of the annotated kind (any number, any list length), sometimes junk."""
    if draw(st.integers(0, 9)) == 0:
        return draw(JUNK)
    tp = draw(st.sampled_from(_members(tp)))
    origin = typing.get_origin(tp)
    if tp is type(None):
        return None
    if origin is typing.Literal:
        return draw(st.one_of(st.sampled_from(typing.get_args(tp)), JSON_SCALARS))
    if origin is list:
        (item,) = typing.get_args(tp) or (Any,)
        size = draw(st.sampled_from([0, 1, 2, 3, 3, 3, 4, 50]))
        return [value_for(draw, item, depth + 1) for _ in range(size)]
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return model_dict(draw, tp, depth + 1) if depth < 4 else draw(JUNK)
    if tp is bool:
        return draw(st.booleans())
    if tp in (int, float):
        return draw(NUMBERS)
    if tp is str:
        return draw(st.text(max_size=10))
    if tp is Path:
        return draw(st.one_of(st.sampled_from(PATHS), st.text(max_size=10)))
    return draw(JUNK)


def model_dict(draw: st.DrawFn, model: type[BaseModel], depth: int = 0) -> dict[str, Any]:
    """A random document for ``model``: a random subset of its keys (required ones usually present), each with
    :func:`value_for`, plus now and then an unknown key."""
    out: dict[str, Any] = {}
    for name, field in model.model_fields.items():
        if (field.is_required() and draw(st.integers(0, 9)) > 0) or draw(st.integers(0, 2)) == 0:
            out[name] = value_for(draw, field.annotation, depth)
    if "shape" in model.model_fields and draw(st.integers(0, 4)) > 0:
        out["shape"] = model.model_fields["shape"].default  # the discriminator, so the generator's keys count
    if draw(st.integers(0, 5)) == 0:
        out[draw(KEY)] = draw(JUNK)
    return out


@st.composite
def scene_documents(draw: st.DrawFn) -> dict[str, Any]:
    doc = model_dict(draw, Scene)
    if draw(st.booleans()):  # usually give objects, often generated ones (they need no files)
        gens = [m for n, m in MODELS.items() if n.endswith("Gen")]
        objects = []
        for _ in range(draw(st.integers(1, 3))):
            ob = model_dict(draw, MODELS["SceneObject"])
            if draw(st.booleans()):
                ob.pop("mesh", None)
                ob["generate"] = model_dict(draw, draw(st.sampled_from(gens)))
            objects.append(ob)
        doc["objects"] = objects
    return doc


# ---------------------------------------------------------------------------------------------------- checks

# one key-path component: [index], or a bare key / a JSON-quoted key, after a dot except at the start
_PART = re.compile(r'\[(\d+)\]|\.?("(?:[^"\\]|\\.)*"|[A-Za-z0-9_-]+)')


def _split_path(rest: str) -> tuple[list[str | int], str]:
    """The key-path components at the start of ``rest`` and what follows them."""
    parts: list[str | int] = []
    pos = 0
    while m := _PART.match(rest, pos):
        if m.end() == pos:
            break
        if m.group(1) is not None:
            parts.append(int(m.group(1)))
        else:
            tok = m.group(2)
            parts.append(json.loads(tok) if tok.startswith('"') else tok)
        pos = m.end()
    return parts, rest[pos:]


def _resolves(doc: Any, parts: list[str | int]) -> bool:
    node = doc
    for part in parts:
        if isinstance(part, int) and isinstance(node, list) and 0 <= part < len(node):
            node = node[part]
        elif isinstance(part, str) and isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return False
    return True


def check_scene_error(exc: SceneError, source: str, doc: Any | None) -> None:
    """Every line ``SOURCE: KEY.PATH: message`` (or ``SOURCE: (top level): ...``); with ``doc``, the key path's
    parent exists in the document (the path names where the problem is)."""
    text = str(exc)
    assert text, "SceneError without a message"
    lines = text.split("\n")
    for line in lines:
        assert line.startswith(f"{source}: "), f"error line does not name the source: {line!r}"
    if doc is None:
        return
    for line in lines:
        rest = line[len(source) + 2 :]
        if rest.startswith("... and "):  # the summary line of a long list of problems
            continue
        if rest.startswith("(top level): "):
            continue
        parts, after = _split_path(rest)
        assert parts and after.startswith(": ") and after[2:], f"error line without a key path and message: {line!r}"
        if "repair" in doc and parts[0] == "objects":
            continue  # a repair scene makes its own object from repair.input
        assert _resolves(doc, parts[:-1]), f"the key path does not lead into the document: {line!r}"


def _validate(doc: Any, base: Path) -> Scene | None:
    try:
        return scene_from_dict(doc, base_dir=base, source="scene")
    except SceneError as exc:
        check_scene_error(exc, "scene", doc)
        return None


# ---------------------------------------------------------------------------------------------------- tests


@fuzz(250)
@given(doc=scene_documents())
def test_random_documents(doc):
    with tempfile.TemporaryDirectory() as d:
        before = tree(Path(d))
        scene = _validate(doc, Path(d))
        assert tree(Path(d)) == before, "validating a scene wrote a file"
        if scene is not None:
            assert isinstance(scene, Scene) and scene.objects


def _base_scenes() -> list[dict[str, Any]]:
    demo = tomllib.loads(SCENES[[p.name for p in SCENES].index("demo_hourglass.toml")].read_text())
    flow = {
        "name": "flow",
        "flow": {"beta": 0.01},
        "objects": [{"name": "s", "kind": "shell", "generate": {"shape": "ellipsoid_surface", "subdivisions": 1}}],
    }
    handles = {
        "dim": 2,
        "objects": [
            {
                "name": "bar",
                "generate": {"shape": "rectangle", "lo": [0, 0], "hi": [4, 1], "resolution": [8, 2]},
                "fixed": [{"box": [[0, 0], [0.1, 1]], "relative": True}],
                "handles": [
                    {
                        "name": "tip",
                        "select": {"box": [[0.9, 0], [1, 1]], "relative": True},
                        "motion": {"type": "rotate", "center": [4, 0.5], "degrees_per_second": 90},
                        "end": 10,
                    }
                ],
                "rest_scripts": [{"type": "bake", "step": 5}],
            },
            {"name": "floor", "kind": "obstacle", "generate": {"shape": "box_polygon", "lo": [-1, -2], "hi": [5, -1]}},
        ],
    }
    return [demo, flow, handles]


BASES = _base_scenes()


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


@fuzz(250)
@given(base=st.sampled_from(range(len(BASES))), data=st.data())
def test_one_change_of_a_valid_scene(base: int, data: st.DataObject) -> None:
    doc = json.loads(json.dumps(BASES[base]))
    assert _validate(json.loads(json.dumps(doc)), Path.cwd()) is not None  # the base is valid
    for _ in range(data.draw(st.integers(1, 2))):
        path = data.draw(st.sampled_from(_paths(doc)), label="path")
        action = data.draw(st.sampled_from(["value", "value", "delete", "unknown-key", "huge-list"]), label="action")
        parent: Any = doc
        for part in path[:-1]:
            parent = parent[part]
        value = data.draw(st.one_of(JUNK, NUMBERS, st.sampled_from(PATHS)), label="value")
        if not path:
            if action == "unknown-key":
                doc[data.draw(KEY)] = value
            continue
        key = path[-1]
        if action == "value":
            parent[key] = value
        elif action == "delete":
            del parent[key]
        elif action == "unknown-key" and isinstance(parent[key], dict):
            parent[key][data.draw(KEY)] = value
        elif action == "huge-list":
            # independent copies, as a parsed file has: a second huge-list inside shared ones would be 20000^2
            parent[key] = json.loads(json.dumps([value] * data.draw(st.sampled_from([0, 4, 1000, 20_000]))))
    with tempfile.TemporaryDirectory() as d:
        before = tree(Path(d))
        _validate(doc, Path(d))
        assert tree(Path(d)) == before


@fuzz(150)
@given(scene=st.sampled_from(SCENES), as_json=st.booleans(), data=st.data())
def test_committed_scenes_mutated(scene, as_json, data):
    text = scene.read_bytes()
    if as_json:
        text = json.dumps(tomllib.loads(text.decode())).encode()
    mutated = data.draw(mutated_bytes(text), label="file")
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / (scene.stem + (".json" if as_json else ".toml"))
        p.write_bytes(mutated)
        before = tree(Path(d))
        try:
            load_scene(p)
        except SceneError as exc:
            check_scene_error(exc, str(p), None)
        assert tree(Path(d)) == before


@pytest.mark.parametrize("scene", SCENES, ids=lambda p: p.name)
def test_committed_scenes_load(scene):
    try:
        load_scene(scene)
    except SceneError as exc:  # a paper scene needs the paper's data (or another scene's output, e.g. Fig. 21 from
        # Fig. 1's): then the message names the key and the missing file, or says where the data is looked for
        msg = str(exc)
        missing = re.search(r"\.mesh: (file not found|the paper's data was not found)", msg)
        assert missing or "repair.input" in msg, exc


# ------------------------------------------------------------------------------------------------ strictness


def _scalar_kind(tp: Any) -> tuple[str, int] | None:
    """("bool" | "number", list depth) when annotation ``tp`` holds booleans or numbers (depth 0: the value itself,
    1: a list of them, 2: a list of lists), else None."""
    for m in _members(tp):
        if m in (bool, int, float):
            return ("bool" if m is bool else "number", 0)
    for m in _members(tp):
        if typing.get_origin(m) is list and typing.get_args(m):
            inner = _scalar_kind(typing.get_args(m)[0])
            if inner is not None:
                return inner[0], inner[1] + 1
    return None


def _scalar_fields() -> list[tuple[str, str, str, int]]:
    """(model, field, kind, list depth) for every field that holds booleans or numbers."""
    out = []
    for mname, model in MODELS.items():
        for fname, field in model.model_fields.items():
            kind = _scalar_kind(field.annotation)
            if kind is not None:
                out.append((mname, fname, *kind))
    return out


def _minimal(model: type[BaseModel]) -> dict[str, Any]:
    """Just enough keys for ``model`` to validate (the required ones), so one field can be varied alone."""
    filled: dict[str, dict[str, Any]] = {
        "FlowConfig": {"beta": 0.1},
        "RepairConfig": {"input": "x.npz"},
        "RepairSelector": {"indices": [0]},
        "SphereSpec": {"center": [0, 0, 0], "radius": 1.0},
        "SelectionSpec": {"indices": [0]},
        "MotionSpec": {"type": "translate", "velocity": [0, 0, 0]},
        "HandleSpec": {"name": "h", "select": {"indices": [0]}, "motion": {"type": "translate"}},
        "KinematicSpec": {"motion": {"type": "translate", "velocity": [0, 0, 0]}},
        "Rotation": {"axis": [0, 0, 1], "degrees": 0.0},
        "SceneObject": {"name": "o", "generate": {"shape": "ball"}},
        "PlasticitySpec": {"yield_stress": 1.0},
        "MaterialStageSpec": {"start": 1},
        "RestScriptSpec": {"type": "bake", "step": 1},
        "KeyframeSpec": {"step": 1},
    }
    return dict(filled.get(model.__name__, {}))


@pytest.mark.parametrize("mname,fname,kind,depth", _scalar_fields(), ids=lambda v: str(v))
def test_scalars_are_strict(mname: str, fname: str, kind: str, depth: int) -> None:
    """A number or a boolean written as a string (alone or in a list) is an error naming the key, never silently
    converted: the README's promise that TOML/JSON ``true`` or ``"10"`` is never a number."""
    model = MODELS[mname]
    if {str, Path} & set(_members(model.model_fields[fname].annotation)):
        return  # the key also takes text (a name, a path)
    texts = ["true", "yes", "1", "on"] if kind == "bool" else ["0", "1", "0.25", "2"]
    values: list[Any] = list(texts)
    if depth == 1:
        values = [[t] * n for t in texts for n in (2, 3)]
    elif depth == 2:
        values = [[["0"] * n, ["1"] * n] for n in (2, 3)] + [[[t] * 3] for t in texts]
    for value in values:
        doc = {**_minimal(model), fname: value}
        if fname in ("box", "sphere", "indices", "group"):  # a selection takes exactly one of these
            doc = {k: v for k, v in doc.items() if k == fname or k not in ("box", "sphere", "indices", "group")}
        try:
            model.model_validate(doc)
        except ValidationError as exc:
            assert fname in str(exc), exc
        else:
            raise AssertionError(f"{mname}.{fname} = {value!r} was accepted")


# ------------------------------------------------------------------------------------------ nothing written


@pytest.mark.parametrize("mesh", PATHS)
def test_hostile_mesh_paths_never_write(tmp_path, monkeypatch, mesh):
    """Mesh paths are only resolved and checked: loading names the missing file or accepts an existing one (it is
    read as a mesh only when the scene is built), and never writes. ``output.dir`` outside the scene's folder is
    resolved, not created."""
    scene_dir, work = tmp_path / "scene", tmp_path / "cwd"
    scene_dir.mkdir()
    work.mkdir()
    monkeypatch.chdir(work)
    elsewhere = tmp_path / "elsewhere"
    doc = {"output": {"dir": str(elsewhere)}, "objects": [{"name": "o", "mesh": mesh}]}
    p = scene_dir / "s.json"
    p.write_text(json.dumps(doc))
    before = tree(tmp_path)
    try:
        scene = load_scene(p)
    except SceneError as exc:
        check_scene_error(exc, str(p), json.loads(p.read_text()))
    else:
        assert scene.output.dir == elsewhere
        assert scene.objects[0].mesh is not None and Path(scene.objects[0].mesh).is_absolute()
    assert tree(tmp_path) == before, "loading a scene wrote a file"
    assert not elsewhere.exists()


def test_scene_values_are_data_not_code(tmp_path, monkeypatch):
    """TOML/JSON values are plain data: strings that look like code or shell commands are never evaluated."""
    monkeypatch.chdir(tmp_path)
    evil = ["__import__('os').system('touch pwned')", "$(touch pwned)", "{{7*7}}", "${HOME}"]
    for value in evil:
        doc = {"name": value, "objects": [{"name": value, "generate": {"shape": "ball"}}]}
        scene = scene_from_dict(doc)
        assert scene.name == value and scene.objects[0].name == value
        with pytest.raises(SceneError):
            scene_from_dict({**doc, "dim": value})
    assert not (tmp_path / "pwned").exists()
    assert list(tmp_path.iterdir()) == []


def test_finite_numbers_only():
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(SceneError, match=r"time\.h"):
            scene_from_dict({"time": {"h": bad}, "objects": [{"name": "o", "generate": {"shape": "ball"}}]})


@pytest.mark.parametrize("key", ["0.0", "a\nscene: time.h: must be > 0", "x: y", "[0]", 'q"uote', ""])
def test_unknown_key_is_quoted(key):
    """Regression: an unknown key holding dots, ': ' or a line break was printed raw, so the key path was ambiguous
    and a key could even add a fake problem line to the message."""
    doc = {key: 1, "objects": [{"name": "o", "generate": {"shape": "ball"}}]}
    with pytest.raises(SceneError) as info:
        scene_from_dict(doc, source="scene")
    assert str(info.value) == f"scene: {json.dumps(key, ensure_ascii=False)}: unknown key"
    check_scene_error(info.value, "scene", doc)


@pytest.mark.parametrize("depth", [33, 500, 990, 995])
@pytest.mark.parametrize("where", ["objects", "zz", "name"])
def test_deep_documents(tmp_path, depth, where):
    """Regression: a JSON document nested ~990 deep parsed, then validation's error message (json.dumps of the
    value) hit RecursionError; ~995 deep the parser did. Both are SceneErrors now, naming the key path."""
    p = tmp_path / "s.json"
    p.write_text(f'{{"{where}": ' + "[" * depth + "]" * depth + "}")
    with pytest.raises(SceneError, match="nested too deeply") as info:
        load_scene(p)
    check_scene_error(info.value, str(p), json.loads(p.read_text()) if depth < 900 else None)


@pytest.mark.parametrize("ext", [".toml", ".json"])
def test_integer_with_5000_digits(tmp_path, ext):
    """Regression: Python's 4300-digit limit on int() made the TOML/JSON parsers raise a bare ValueError."""
    p = tmp_path / f"s{ext}"
    big = "1" + "0" * 5000
    p.write_text(f"[time]\nsteps = {big}\n" if ext == ".toml" else f'{{"time": {{"steps": {big}}}}}')
    with pytest.raises(SceneError, match="4300 digits"):
        load_scene(p)


def test_many_problems_are_counted():
    """Regression: 10^4 wrong list entries gave a SceneError of 10^4 lines; now the first 20 and a count."""
    doc = {"objects": [{"name": f"o{i}", "mesh": f"missing{i}.obj", "scale": "x"} for i in range(5000)]}
    with pytest.raises(SceneError) as info:
        scene_from_dict(doc, source="scene")
    lines = str(info.value).splitlines()
    assert len(lines) == 21 and lines[-1] == "scene: ... and 4980 more problems", lines[-3:]
    check_scene_error(info.value, "scene", doc)
    doc = {"objects": [{"name": f"o{i}", "mesh": f"missing{i}.obj"} for i in range(30)]}
    with pytest.raises(SceneError) as info:
        scene_from_dict(doc, source="scene")
    assert str(info.value).splitlines()[-1] == "scene: ... and 10 more problems"


@pytest.mark.parametrize(
    "doc",
    [
        {"objects": [{"name": "o", "generate": {"shape": "ball"}, "fixed": [{"indices": [2**64]}]}]},
        {"time": {"steps": 10**30}, "objects": [{"name": "o", "generate": {"shape": "ball"}}]},
        {"objects": [{"name": "o", "mesh": "m.npz", "kind": "shell", "frame": 2**63}]},
    ],
)
def test_integers_are_64_bit(doc):
    """Regression: integers are 64-bit as in the TOML specification; a vertex index of 2^64 passed validation and
    reached numpy as an OverflowError when the scene was built."""
    with pytest.raises(SceneError, match="must be <= 9223372036854775807") as info:
        scene_from_dict(doc, source="scene")
    check_scene_error(info.value, "scene", doc)


@pytest.mark.parametrize(
    "kind,generate",
    [
        ("deformable", {"shape": "ball", "resolution": 10**5}),
        ("deformable", {"shape": "tet_box", "resolution": [1, 1, 10**9]}),
        ("deformable", {"shape": "ellipsoid", "resolution": 1000}),
        ("shell", {"shape": "cylinder_surface", "segments": 10**9}),
        ("shell", {"shape": "box_surface", "resolution": 10**5}),
        ("shell", {"shape": "hourglass_surface", "rings": 10**8}),
    ],
)
def test_generated_meshes_are_bounded(kind, generate):
    """Regression: a generator resolution of 10^5 passed validation and asked numpy for petabytes when the scene
    was built (a MemoryError traceback; 10^9 segments, 7.5 GB, would have been allocated on a large machine)."""
    doc = {"objects": [{"name": "o", "kind": kind, "generate": generate}]}
    with pytest.raises(SceneError, match=r"would make .* cells, more than 1e\+07") as info:
        scene_from_dict(doc, source="scene")
    check_scene_error(info.value, "scene", doc)


def test_noise_smoothing_is_bounded():
    """Regression: ellipsoid_surface smoothing = 10^18 passed validation and looped 10^18 times when built."""
    doc = {
        "flow": {"beta": 0.1},
        "objects": [
            {
                "name": "o",
                "kind": "shell",
                "generate": {"shape": "ellipsoid_surface", "noise": 0.1, "smoothing": 10**18},
            }
        ],
    }
    with pytest.raises(SceneError, match=r"objects\[0\]\.generate\.smoothing: must be <= 10000"):
        scene_from_dict(doc, source="scene")
