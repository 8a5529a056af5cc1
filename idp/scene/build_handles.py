"""Scene specs → runtime selections and motions (:mod:`idp.mesh.selection`, :mod:`idp.stepper.motions`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from idp.errors import SceneError
from idp.mesh.selection import Selection
from idp.stepper import motions as mo


def selection_from_spec(spec, groups: dict[str, np.ndarray] | None = None) -> Selection:
    """A :class:`~idp.mesh.selection.Selection` from a ``SelectionSpec``; ``groups``: the mesh's vertex groups."""
    selection = _base_selection(spec, groups)
    if getattr(spec, "exclude", None) is not None:
        selection.exclude = selection_from_spec(spec.exclude, groups)
    return selection


def _base_selection(spec, groups: dict[str, np.ndarray] | None) -> Selection:
    if spec.group is not None:
        groups = groups or {}
        if spec.group not in groups:
            known = ", ".join(sorted(groups)) or "none"
            raise SceneError(f"select.group: the mesh has no vertex group {spec.group!r} (it has: {known})")
        return Selection(indices=np.asarray(groups[spec.group], dtype=np.int64))
    if spec.box is not None:
        return Selection(box=(np.asarray(spec.box[0], float), np.asarray(spec.box[1], float)), relative=spec.relative)
    if spec.sphere is not None:
        return Selection(
            sphere=(np.asarray(spec.sphere.center, float), float(spec.sphere.radius)), relative=spec.relative
        )
    return Selection(indices=np.asarray(spec.indices, dtype=np.int64))


def _vec(v, d: int | None = None) -> np.ndarray | None:
    return None if v is None else np.asarray(v, dtype=float)


def _required_vec(v) -> np.ndarray:
    """A field the ``MotionSpec`` validator requires for this motion type (never None here)."""
    return np.asarray(v, dtype=float)


def _load_targets(path: Path, key: str) -> np.ndarray:
    """(k, d) or (F, k, d) float array from .npy / .npz (first array, or the one named ``targets``)."""
    try:
        data = np.load(path, allow_pickle=False)
        if isinstance(data, np.lib.npyio.NpzFile):
            names = data.files
            if not names:
                raise ValueError("the archive holds no array")
            arr = data["targets"] if "targets" in names else data[names[0]]
        else:
            arr = data
        arr = np.asarray(arr, dtype=float)
    except (OSError, ValueError) as exc:
        raise SceneError(f"{key}.file: cannot read {path}: {exc}") from exc
    if arr.ndim not in (2, 3) or not np.all(np.isfinite(arr)):
        raise SceneError(f"{key}.file: {path} must hold finite (k, d) or (frames, k, d) targets, got shape {arr.shape}")
    return arr


def motion_from_spec(spec, key: str, dt: float) -> mo.Motion:
    """A :class:`~idp.stepper.motions.Motion` from a ``MotionSpec`` (``key`` names it in errors; ``dt`` = √h)."""
    t = spec.type
    center = _vec(spec.center)
    if t == "fixed":
        return mo.Fixed()
    if t == "translate":
        return mo.Translate(_required_vec(spec.velocity))
    if t == "rotate":
        return mo.Rotate(float(spec.degrees_per_second), center if center is not None else 0.0, _vec(spec.axis))
    if t == "scale":
        about = None if spec.about == "selection" else (center if center is not None else 0.0)
        return mo.Scale(_required_vec(spec.rate), about, spec.law)
    if t == "keyframes":
        keys = []
        for k in spec.keyframes:
            d = None if k.translate is None else len(k.translate)
            tr = _required_vec(k.translate) if k.translate is not None else 0.0
            if k.rotate is None or k.rotate.degrees == 0:
                rv = np.zeros(3 if (d or 3) == 3 else 1)
            elif k.rotate.axis is None:  # 2D
                rv = np.array([math.radians(k.rotate.degrees)])
            else:
                ax = np.asarray(k.rotate.axis, float)
                rv = ax / np.linalg.norm(ax) * math.radians(k.rotate.degrees)
            keys.append(mo.Keyframe(k.step * dt, tr, rv, np.asarray(k.scale, dtype=float)))
        return mo.Keyframes(keys, center if center is not None else 0.0, smooth=spec.interpolation == "smooth")
    if t == "roll":
        return mo.Roll(
            _required_vec(spec.axis),
            _required_vec(spec.direction),
            _required_vec(spec.center),
            float(spec.speed),
            float(spec.pitch),
        )
    # targets
    if spec.offset is not None:
        return mo.PathTargets(offset=_vec(spec.offset), quota=spec.quota, source=f"{key}.offset")
    arr = _load_targets(Path(spec.file), key)
    src = f"{key}.file ({spec.file})"
    if arr.ndim == 2:
        return mo.PathTargets(final=arr, quota=spec.quota, source=src)
    return mo.FrameTargets(arr, dt, source=src)
