"""Refuse to resume a run with a scene other than the one it was started with.

A resumed run continues from the interrupted run's checkpoint; with a changed scene (another material, contact
distance, mesh, handle) its later frames would belong to neither scene. The run folder keeps the resolved
scene (``scene.resolved.json``, every default filled in); a resume compares the new resolved scene with it
and names every differing key path. Only the keys that say how far to run or where (``time.steps``,
``output.dir``) may change; ``force`` resumes anyway, with a warning naming the keys.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any

from idp.errors import SceneError

log = logging.getLogger("idp")

RESUMABLE_CHANGES = frozenset({"time.steps", "output.dir"})
_SHOWN = 12  # key paths named in the message; the rest are counted


def _join(prefix: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{prefix}[{key}]"
    return f"{prefix}.{key}" if prefix else key


def scene_differences(old: Any, new: Any, prefix: str = "") -> list[str]:
    """The key paths (``objects[0].material.youngs_modulus``) where two resolved scene dicts differ."""
    if isinstance(old, dict) and isinstance(new, dict):
        out: list[str] = []
        for key in list(old) + [k for k in new if k not in old]:
            if key not in old or key not in new:
                out.append(_join(prefix, key))
            else:
                out += scene_differences(old[key], new[key], _join(prefix, key))
        return out
    if isinstance(old, list) and isinstance(new, list):
        out = []
        for i in range(max(len(old), len(new))):
            if i >= len(old) or i >= len(new):
                out.append(_join(prefix, i))
            else:
                out += scene_differences(old[i], new[i], _join(prefix, i))
        return out
    return [] if old == new and type(old) is type(new) else [prefix or "(the whole scene)"]


def _appended_stage(path: str, old: dict[str, Any]) -> bool:
    """``stages[k]`` (or a key inside it) for a stage after the earlier run's last: appending stages to a staged
    run is no change to what it has done."""
    m = re.match(r"stages\[(\d+)\]", path)
    return m is not None and int(m.group(1)) >= len(old.get("stages") or [])


def check_resume_scene(out: Path, resolved: dict[str, Any], *, force: bool = False) -> None:
    """SceneError naming the differing keys when ``resolved`` is not the scene the run in ``out`` was started
    with (``out/scene.resolved.json``); nothing when they agree, when there is no earlier scene, or with
    ``force`` (then a warning). Stages appended after the earlier run's last stage are no change."""
    path = Path(out) / "scene.resolved.json"
    if not path.is_file():
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        if not force:
            raise SceneError(
                f"cannot resume {out}: its scene record {path} is unreadable ({exc}); pass --force to resume anyway"
            ) from None
        log.warning("resuming %s without comparing scenes: %s is unreadable", out, path)
        return
    changed = [
        p for p in scene_differences(old, resolved) if p not in RESUMABLE_CHANGES and not _appended_stage(p, old)
    ]
    if changed:  # keys a newer idp added at their defaults are no change: compare with the record read by this idp
        upgraded = _upgraded(old, Path(out))
        if upgraded is not None:
            changed = [
                p
                for p in scene_differences(upgraded, resolved)
                if p not in RESUMABLE_CHANGES and not _appended_stage(p, old)
            ]
    if not changed:
        return
    shown = ", ".join(changed[:_SHOWN]) + (f" and {len(changed) - _SHOWN} more" if len(changed) > _SHOWN else "")
    if force:
        log.warning("resuming %s with a changed scene (forced): %s", out, shown)
        return
    raise SceneError(
        f"cannot resume {out}: the scene differs from the one the run was started with in {shown}. "
        "Run it into a new folder, restore those keys, or force the resume (--force)"
    )


def _upgraded(old: dict[str, Any], base: Path) -> dict[str, Any] | None:
    """The earlier run's resolved scene read by this version of idp (keys it added since then filled in with their
    defaults), or None when that record no longer reads."""
    from idp.scene.load import resolved_scene_dict, scene_from_dict

    try:
        return resolved_scene_dict(scene_from_dict(old, base_dir=base))
    except Exception:  # a record the current schema refuses: compare as written
        return None
