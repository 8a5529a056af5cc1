"""Reading, validating, resolving and writing scene files (TOML or JSON)."""

from __future__ import annotations

import difflib
import json
import math
import os
import re
import sys
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from idp.errors import SceneError
from idp.fs import is_dir, is_file, why
from idp.paper_data import DATA_PREFIX, resolve_data_path
from idp.scene.schema import MODELS, Scene
from idp.scene.schema_base import unwrap_type

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "dump_scene_toml",
    "format_validation_error",
    "load_scene",
    "read_scene_data",
    "resolved_scene_dict",
    "scene_from_dict",
]


# ---------------------------------------------------------------------------------------------
# Loading


def load_scene(path: str | Path) -> Scene:
    """Read a ``.toml`` or ``.json`` scene, validate it and resolve paths against its folder.

    The scene ``name`` defaults to the file stem.  Any problem raises :class:`SceneError`
    whose message starts with the file name.
    """
    p = Path(path)
    data = read_scene_data(p)
    if "name" not in data:
        data = {"name": p.stem, **data}
    return scene_from_dict(data, base_dir=p.parent.absolute(), source=str(p))


def read_scene_data(path: str | Path) -> dict[str, Any]:
    """A ``.toml`` or ``.json`` file parsed into plain data (a table at the top level), not yet validated:
    what :func:`load_scene` validates, and what a batch applies its overrides to. :class:`SceneError` names
    the file."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in (".toml", ".json"):
        raise SceneError(f"{p}: unknown scene file extension '{p.suffix}' (expected .toml or .json)")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SceneError(f"{p}: cannot read scene file: {err}") from err
    data: Any
    try:
        if ext == ".toml":
            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as err:
                raise SceneError(f"{p}: TOML syntax error: {err}") from err
        else:
            try:
                data = json.loads(text)
            except json.JSONDecodeError as err:
                raise SceneError(
                    f"{p}: JSON syntax error: {err.msg} (at line {err.lineno}, column {err.colno})"
                ) from err
    except RecursionError:  # the parsers recurse per nesting level
        raise SceneError(
            f"{p}: (top level): nested too deeply (more than {MAX_DEPTH} levels of tables and arrays)"
        ) from None
    except ValueError as err:  # an integer of more than 4300 digits (Python's int conversion limit)
        raise SceneError(f"{p}: cannot read scene file: {err}") from None
    if not isinstance(data, dict):
        raise SceneError(f"{p}: the top level must be a table/object (got {type(data).__name__})")
    return data


#: deepest nesting of tables and arrays a scene may have: the schema's deepest key,
#: objects[i].handles[j].motion.keyframes[k].rotate.axis[l], is 8 levels down. Deeper documents are refused before
#: validation, whose error messages (and pydantic) would otherwise recurse into them.
MAX_DEPTH = 32


def _too_deep(data: Any) -> list[str | int] | None:
    """The key path of the first value nested more than MAX_DEPTH tables/arrays deep, or None (iterative)."""
    stack: list[tuple[Any, list[str | int]]] = [(data, [])]
    while stack:
        node, path = stack.pop()
        if isinstance(node, dict | list):
            if len(path) >= MAX_DEPTH:
                return path
            items = node.items() if isinstance(node, dict) else enumerate(node)
            stack.extend((value, [*path, key]) for key, value in items)
    return None


def _absolute(p: Path, base: Path) -> Path:
    try:
        p = p.expanduser()
    except RuntimeError:  # ~user of an unknown user: kept as written, then reported as not found
        pass
    return Path(os.path.normpath(p if p.is_absolute() else base / p))


def scene_from_dict(data: dict[str, Any], base_dir: Path | None = None, *, source: str = "scene") -> Scene:
    """Validate a scene given as plain data (as parsed from TOML/JSON).

    Relative mesh paths are resolved against ``base_dir`` (or the working directory) and stored
    absolute; every mesh file must exist.  A relative ``output.dir`` is resolved against
    ``base_dir`` when given, else kept as is.  ``source`` prefixes every error line.
    """
    if not isinstance(data, dict):
        raise SceneError(f"{source}: the top level must be a table/object (got {type(data).__name__})")
    deep = _too_deep(data)
    if deep is not None:
        raise SceneError(
            f"{source}: {_path_str(deep)}: nested too deeply (more than {MAX_DEPTH} levels of tables and arrays)"
        )
    try:
        scene = Scene.model_validate(data)
    except ValidationError as err:
        raise SceneError(format_validation_error(err, source)) from err
    base = Path(base_dir).absolute() if base_dir is not None else Path.cwd()
    missing = []
    if scene.repair is not None:
        r = scene.repair
        if str(r.input).startswith(DATA_PREFIX):
            try:
                r.input = resolve_data_path(str(r.input))
            except FileNotFoundError as exc:
                raise SceneError(f"{source}: repair.input: {exc}") from None
        r.input = _absolute(r.input, base)
        scene.objects[0].mesh = r.input  # a sequence (a folder or glob too): opened and checked when built
    for i, ob in enumerate(scene.objects):
        missing += _resolve_object_paths(ob, f"objects[{i}]", base, source, mesh=scene.repair is None)
    for k, stage in enumerate(scene.stages or []):  # objects a stage adds: the same paths, the same folder
        for i, ob in enumerate(stage.add):
            missing += _resolve_object_paths(ob, f"stages[{k}].add[{i}]", base, source, mesh=True)
    if missing:
        raise SceneError(_problem_lines(missing, source))
    if base_dir is not None:
        scene.output.dir = _absolute(scene.output.dir, base)
    return scene


def _resolve_object_paths(ob: Any, where: str, base: Path, source: str, *, mesh: bool) -> list[str]:
    """Make an object's file paths absolute (against ``base``; ``data:`` paths against the paper's data) and
    return one line per missing file: its mesh (unless ``mesh`` is False: a repair sequence, checked when
    opened), the rest state an earlier stage saved, and per-vertex handle target files."""
    missing: list[str] = []
    if ob.mesh is not None and str(ob.mesh).startswith(DATA_PREFIX):
        try:
            ob.mesh = resolve_data_path(str(ob.mesh))
        except FileNotFoundError as exc:
            return [f"{source}: {where}.mesh: {exc}"]
    if ob.mesh is not None and mesh:
        ob.mesh = _absolute(ob.mesh, base)
        sequence = ob.frame is not None and (is_dir(ob.mesh) or any(ch in str(ob.mesh) for ch in "*?["))
        if not is_file(ob.mesh) and not sequence:  # a sequence folder or glob is checked when opened
            missing.append(f"{source}: {where}.mesh: file not found: {ob.mesh}{why(ob.mesh)}")
    if ob.rest_state is not None:
        ob.rest_state = _absolute(ob.rest_state, base)
        if not is_file(ob.rest_state):
            missing.append(f"{source}: {where}.rest_state: file not found: {ob.rest_state}{why(ob.rest_state)}")
    for j, hd in enumerate(ob.handles):
        if hd.motion.file is not None:
            hd.motion.file = _absolute(hd.motion.file, base)
            if not is_file(hd.motion.file):
                missing.append(
                    f"{source}: {where}.handles[{j}].motion.file: file not found: {hd.motion.file}{why(hd.motion.file)}"
                )
    return missing


# ---------------------------------------------------------------------------------------------
# Error formatting


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _walk(root: Any, loc: tuple[str | int, ...]) -> tuple[list[str | int], Any]:
    """Turn a pydantic location into key-path parts (dropping union tags).

    Returns the parts and the model class in which the last key was looked up (or None).
    """
    parts: list[str | int] = []
    tp: Any = root
    last_model: Any = None
    for item in loc:
        tp = unwrap_type(tp)
        if isinstance(item, int):
            parts.append(item)
            args = typing.get_args(tp) if typing.get_origin(tp) is list else ()
            tp = args[0] if args else None
            continue
        if _is_model(tp):
            parts.append(item)
            last_model = tp
            field = tp.model_fields.get(item)
            tp = field.annotation if field is not None else None
            continue
        members = [m for m in typing.get_args(tp) if _is_model(unwrap_type(m))] if tp is not None else []
        if members:  # a discriminated-union tag such as 'ball'
            match = [
                unwrap_type(m)
                for m in members
                if "shape" in unwrap_type(m).model_fields and unwrap_type(m).model_fields["shape"].default == item
            ]
            tp = match[0] if match else None
            continue
        if not item.isidentifier() or item in ("float", "int", "str", "bool", "list", "dict"):
            continue  # a union-member tag ('float', 'list[float]', 'literal[...]', ...)
        parts.append(item)
        tp = None
    return parts, last_model


def _path_str(parts: list[str | int]) -> str:
    """``objects[0].material.poisson_ratio``; a key that is not a bare word is quoted as in TOML
    (``objects[0]."a.b"``), so an unknown key holding dots, ": " or a line break cannot blur the path or the
    one-line-per-problem message."""
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{_key(p)}" if out else _key(p))
    return out


def _join(base: str, sub: str) -> str:
    if not sub:
        return base
    if not base:
        return sub
    return base + sub if sub.startswith("[") else f"{base}.{sub}"


def _show(v: Any) -> str:
    """A value as it would appear in a scene file (short)."""
    if isinstance(v, bool):
        s = "true" if v else "false"
    elif isinstance(v, str):
        s = json.dumps(v, ensure_ascii=False)
    elif isinstance(v, float) and not math.isfinite(v):
        s = repr(v)
    elif isinstance(v, (int, float)):
        s = repr(v)
    else:
        try:
            s = json.dumps(v, ensure_ascii=False, default=str)
        except (TypeError, ValueError):
            s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def _message(err: Any, last_model: Any, key: Any) -> str:
    """Human message for one pydantic error (without its path)."""
    t = err["type"]
    ctx = err.get("ctx") or {}
    got = f" (got {_show(err.get('input'))})"
    if t == "missing":
        return "required key is missing"
    if t == "extra_forbidden":
        hint = ""
        if last_model is not None and isinstance(key, str):
            close = difflib.get_close_matches(key, list(last_model.model_fields), n=1, cutoff=0.6)
            if close:
                hint = f" (did you mean '{close[0]}'?)"
        return f"unknown key{hint}"
    bounds = {
        "greater_than": ("gt", ">"),
        "greater_than_equal": ("ge", ">="),
        "less_than": ("lt", "<"),
        "less_than_equal": ("le", "<="),
    }
    if t in bounds:
        k, op = bounds[t]
        return f"must be {op} {_show(ctx.get(k))}{got}"
    if t in ("int_type", "int_parsing", "int_from_float"):
        return f"must be an integer{got}"
    if t in ("float_type", "float_parsing"):
        return f"must be a number{got}"
    if t == "finite_number":
        return f"must be a finite number{got}"
    if t in ("bool_type", "bool_parsing"):
        return f"must be true or false{got}"
    if t == "string_type":
        return f"must be a string{got}"
    if t == "string_too_short":
        return "must not be empty"
    if t in ("list_type", "tuple_type"):
        return f"must be a list{got}"
    if t == "too_short":
        return f"must have at least {ctx.get('min_length')} entries{got}"
    if t == "too_long":
        return f"must have at most {ctx.get('max_length')} entries{got}"
    if t in ("model_type", "model_attributes_type", "dict_type"):
        return f"must be a table{got}"
    if t == "literal_error":
        return f"must be one of {ctx.get('expected')}{got}"
    if t in ("path_type", "path_parsing"):
        return f"must be a path string{got}"
    if t == "union_tag_invalid":
        return f"unknown shape {_show(ctx.get('tag'))}; expected one of: {ctx.get('expected_tags')}"
    if t == "union_tag_not_found":
        return "required key is missing (it selects the generator)"
    if t == "value_error":
        return str(ctx.get("error", err["msg"]))
    msg = str(err.get("msg", t))
    return msg[:1].lower() + msg[1:]


def format_validation_error(err: ValidationError, source: str) -> str:
    """One line per problem: ``SOURCE: objects[0].material.poisson_ratio: must be < 0.5 (got 0.5)``."""
    root = MODELS.get(err.title, Scene)
    lines: list[str] = []
    for e in err.errors(include_url=False):
        parts, last_model = _walk(root, tuple(e["loc"]))
        path = _path_str(parts)
        if e["type"] == "scene_rule":
            for sub, msg in (e.get("ctx") or {}).get("problems", []):
                lines.append(f"{source}: {_join(path, sub) or '(top level)'}: {msg}")
            continue
        if e["type"] in ("union_tag_invalid", "union_tag_not_found"):
            path = _join(path, "shape")
        msg = _message(e, last_model, parts[-1] if parts else None)
        lines.append(f"{source}: {path or '(top level)'}: {msg}")
    return _problem_lines(lines, source)


#: problems listed in one SceneError; the rest are counted (10^5 bad list entries are not 10^5 lines)
MAX_PROBLEMS = 20


def _problem_lines(lines: list[str], source: str) -> str:
    unique = list(dict.fromkeys(lines))
    if len(unique) > MAX_PROBLEMS:
        more = len(unique) - MAX_PROBLEMS
        unique = [*unique[:MAX_PROBLEMS], f"{source}: ... and {more} more problem{'s' if more > 1 else ''}"]
    return "\n".join(unique)


# ---------------------------------------------------------------------------------------------
# Writing


def resolved_scene_dict(scene: Scene) -> dict[str, Any]:
    """The scene with every default filled in, as JSON/TOML-safe plain data (no nulls)."""
    return scene.model_dump(mode="json", exclude_none=True)


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else json.dumps(k, ensure_ascii=False)  # fullmatch: "$" passes "a\n"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)


def _emit(table: dict[str, Any], prefix: str, out: list[str]) -> None:
    """Write a table's plain keys, then its sub-tables and arrays of tables."""
    for k, v in table.items():
        if v is None or isinstance(v, dict) or _is_table_array(v):
            continue
        out.append(f"{_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, dict):
            out.append("")
            out.append(f"[{name}]")
            _emit(v, name, out)
        elif _is_table_array(v):
            for item in v:
                out.append("")
                out.append(f"[[{name}]]")
                _emit(item, name, out)


def dump_scene_toml(scene: Scene) -> str:
    """The resolved scene as TOML text that :func:`load_scene` reads back to an equal scene."""
    out = ["# idp scene, resolved: every default filled in"]
    _emit(resolved_scene_dict(scene), "", out)
    return "\n".join(out) + "\n"
