"""Key paths into a scene (``contact.dhat``, ``objects[0].material.youngs_modulus``) and overrides of a scene's
plain data by key path, as a batch applies them (:mod:`idp.scene.batch_schema`) before the scene is validated."""

from __future__ import annotations

import re
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from idp.scene.schema import Scene
from idp.scene.schema_base import unwrap_type

__all__ = ["KeyPath", "apply_override", "field_type", "format_key_path", "is_path_field", "parse_key_path"]

KeyPath = tuple[str | int, ...]

_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
_SEGMENT = re.compile(rf"({_NAME})((?:\[\d+\])*)")
_INDEX = re.compile(r"\[(\d+)\]")


def parse_key_path(text: str) -> KeyPath:
    """``"objects[0].material.youngs_modulus"`` → ``("objects", 0, "material", "youngs_modulus")``.

    Names are separated by dots; a name may be followed by list indices ``[i]`` (0-based). ValueError says
    what is wrong with the text."""
    if not isinstance(text, str) or not text:
        raise ValueError("a key path must be a non-empty string such as contact.dhat or objects[0].mesh")
    parts: list[str | int] = []
    for segment in text.split("."):
        m = _SEGMENT.fullmatch(segment)
        if m is None:
            raise ValueError(
                f"not a key path: {text!r} (names joined by dots, each name optionally followed by [i], "
                "e.g. objects[0].material.youngs_modulus)"
            )
        parts.append(m.group(1))
        parts.extend(int(i) for i in _INDEX.findall(m.group(2)))
    return tuple(parts)


def format_key_path(parts: KeyPath) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def field_type(parts: KeyPath, root: type[BaseModel] = Scene) -> Any:
    """The annotated type of the scene field at ``parts`` (Optional and Annotated stripped), or None where the
    schema has no such key or the path runs into a union (a generator's shape-dependent keys)."""
    tp: Any = root
    for part in parts:
        tp = unwrap_type(tp)
        if isinstance(part, int):
            if typing.get_origin(tp) is not list:
                return None
            tp = typing.get_args(tp)[0]
        elif isinstance(tp, type) and issubclass(tp, BaseModel):
            field = tp.model_fields.get(part)
            if field is None:
                return None
            tp = field.annotation
        else:
            return None
    return unwrap_type(tp)


def is_path_field(parts: KeyPath) -> bool:
    """Whether the scene field at ``parts`` holds a file path (``objects[i].mesh``, ``repair.input``, ...)."""
    return field_type(parts) is Path


def apply_override(data: dict[str, Any], parts: KeyPath, value: Any) -> None:
    """Set ``value`` at ``parts`` in a scene's plain data, creating missing tables on the way (a key the base
    scene leaves at its default). A list index must name an entry the scene has. ValueError (without the
    source) says where the path cannot be followed."""
    node: Any = data
    for k, part in enumerate(parts):
        last = k == len(parts) - 1
        here = format_key_path(parts[:k]) or "the scene"
        if isinstance(part, int):
            if not isinstance(node, list):
                raise ValueError(f"{here} is not a list in the scene (it is {_describe(node)}), so [{part}] is invalid")
            if part >= len(node):
                raise ValueError(
                    f"{format_key_path(parts[: k + 1])}: no such entry ({here} has {len(node)} "
                    f"entr{'y' if len(node) == 1 else 'ies'} in the scene)"
                )
            if last:
                node[part] = value
            else:
                node = node[part]
            continue
        if not isinstance(node, dict):
            raise ValueError(f"{here} is not a table in the scene (it is {_describe(node)}), so .{part} is invalid")
        if last:
            node[part] = value
        else:
            if part not in node:
                if isinstance(parts[k + 1], int):
                    have, want = format_key_path(parts[: k + 1]), format_key_path(parts[: k + 2])
                    raise ValueError(f"{want}: no such entry (the scene has no {have})")
                node[part] = {}
            node = node[part]


def _describe(v: Any) -> str:
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        return f"a list of {len(v)}"
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."
