"""Run statistics: ``stats.json`` with metadata, one record per step and a summary.

File layout (strict JSON, always complete on disk because every rewrite is atomic)::

    {
     "meta": {...},
     "steps": [
      {...},            one compact line per step
      ...
     ],
     "summary": {...} | null
    }

Non-finite floats are stored as the strings ``"inf"``, ``"-inf"`` and ``"nan"`` (JSON has no
such numbers); :func:`load_stats` turns them back into floats by default.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import os
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from idp._faults import kill_point

_NONFINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def _float(v: float) -> float | str:
    if math.isfinite(v):
        return v
    if math.isnan(v):
        return "nan"
    return "inf" if v > 0 else "-inf"


def _array(a: np.ndarray) -> Any:
    """A numpy array as nested lists of JSON-safe scalars."""
    if a.dtype.kind == "f":
        if np.isfinite(a).all():
            return a.tolist()
        obj = a.astype(object)
        obj[np.isnan(a)] = "nan"
        obj[np.isposinf(a)] = "inf"
        obj[np.isneginf(a)] = "-inf"
        return obj.tolist()
    if a.dtype.kind in "biu":
        return a.tolist()
    return [to_jsonable(v) for v in a.tolist()] if a.ndim else to_jsonable(a.item())


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` recursively into something ``json.dumps(..., allow_nan=False)`` accepts.

    numpy scalars/arrays -> Python numbers/lists; Path -> str; dataclasses -> dict; Enum -> value;
    tuples/sets -> lists; dict keys -> str; date/time -> ISO string; inf/-inf/nan -> the strings
    "inf"/"-inf"/"nan"; anything else unknown -> ``str(obj)`` (stats must never crash a run).
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return _float(float(obj))
    if isinstance(obj, np.generic):
        if isinstance(obj, np.bool_):
            return bool(obj)
        if isinstance(obj, np.integer):
            return int(obj)
        if isinstance(obj, np.floating):
            return _float(float(obj))
        return to_jsonable(obj.item())
    if isinstance(obj, np.ndarray):
        return _array(obj)
    if isinstance(obj, dict):
        return {str(to_jsonable(k)) if not isinstance(k, str) else k: to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, (_dt.datetime, _dt.date, _dt.time)):
        return obj.isoformat()
    return str(obj)


def _dumps(obj: Any) -> str:
    return json.dumps(to_jsonable(obj), allow_nan=False, separators=(",", ":"))


def _indent(text: str, pad: str) -> str:
    return text.replace("\n", "\n" + pad)


class StatsRecorder:
    """stats.json with run metadata, one record per step, and a summary; rewritten atomically after every step."""

    def __init__(self, path: str | Path, meta: dict, steps: list[dict] | None = None) -> None:
        """``steps``: records kept from an interrupted run, in the file from its first write (a resumed run killed
        before it had re-added them one by one would otherwise leave a file without them)."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._meta_text = json.dumps(to_jsonable(meta), allow_nan=False, indent=1)
        self._steps: list[dict] = [dict(r) for r in steps or []]
        self._step_text: list[str] = [_dumps(r) for r in steps or []]  # each record serialised once, when added
        self._summary_text = "null"
        self._flush()

    def add_step(self, record: dict) -> None:
        """Append one step record and rewrite the file atomically."""
        text = _dumps(record)
        self._steps.append(dict(record))
        self._step_text.append(text)
        self._flush()

    def set_summary(self, summary: dict) -> None:
        """Set (replace) the run summary and rewrite the file atomically."""
        self._summary_text = json.dumps(to_jsonable(summary), allow_nan=False, indent=1)
        self._flush()

    @property
    def steps(self) -> list[dict]:
        """The records added so far (as given, shallow copies), oldest first."""
        return list(self._steps)

    def _flush(self) -> None:
        steps = "[]" if not self._step_text else "[\n  " + ",\n  ".join(self._step_text) + "\n ]"
        text = (
            '{\n "meta": '
            + _indent(self._meta_text, " ")
            + ',\n "steps": '
            + steps
            + ',\n "summary": '
            + _indent(self._summary_text, " ")
            + "\n}\n"
        )
        tmp = self.path.with_name(self.path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        kill_point("stats")
        os.replace(tmp, self.path)


def _decode(obj: Any) -> Any:
    if isinstance(obj, str):
        return _NONFINITE.get(obj, obj)
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _decode(v) for k, v in obj.items()}
    return obj


def load_stats(path: str | Path, *, decode_nonfinite: bool = True) -> dict:
    """Read a stats.json; with ``decode_nonfinite`` the strings "inf"/"-inf"/"nan" become floats."""
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    return _decode(data) if decode_nonfinite else data
