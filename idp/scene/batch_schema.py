"""Batch spec files (``idp batch SPEC.toml``): which scene runs make up a batch, expanded into jobs.

A spec names a base scene and a cartesian ``grid`` of overrides by key path, and/or a list of ``cases`` (override
sets, each on the base scene or its own), and/or plain scene ``jobs`` (e.g. repair scenes), with optional
overrides::

    name = "bunny_sweep"
    retries = 1                                  # extra attempts of a job after a failure
    [base]
    scene = "scene.toml"                         # relative to the spec file
    [set]                                        # overrides of every job (applied first)
    "time.steps" = 20
    [grid]                                       # cartesian product (the last key varies fastest)
    "objects[0].material.youngs_modulus" = [1e4, 1e5]
    "contact.dhat" = [1e-3, 2e-3]
    [[cases]]
    name = "stiff"                               # optional; else made from the overrides
    set = { "time.steps" = 3 }
    [[jobs]]
    scene = "repair.toml"
    set = { "contact.dhat" = 0.02 }

:func:`load_batch` validates the spec and every job's scene up front (the overridden scene is validated as a
scene file would be, so an unknown key path, an index past the end of a list or a bad value fails before any
job runs, naming the spec, the job and the key path); meshes are not built here, only checked to exist.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, Strict, ValidationError, model_validator

from idp.errors import SceneError
from idp.paper_data import DATA_PREFIX
from idp.scene.load import (
    _problem_lines,
    dump_scene_toml,
    format_validation_error,
    load_scene,
    read_scene_data,
    scene_from_dict,
)
from idp.scene.overrides import KeyPath, apply_override, is_path_field, parse_key_path
from idp.scene.schema import MODELS, Scene
from idp.scene.schema_base import Name, PosInt, _Model, rule_error

__all__ = ["BatchJob", "BatchSpec", "load_batch", "load_batch_spec"]

#: a job's folder name: starts with a letter or digit, then letters, digits and ``. _ = + -`` (at most 100)
JOB_NAME = r"^[A-Za-z0-9][A-Za-z0-9._=+-]{0,99}$"
JobName = Annotated[str, Field(pattern=JOB_NAME)]


class BaseSpec(_Model):
    """The scene the ``grid`` and the ``cases`` without their own scene override."""

    scene: Path


class CaseSpec(_Model):
    """One job: the base scene (or ``scene``) with the overrides in ``set``."""

    name: JobName | None = None
    scene: Path | None = None
    set: dict[str, Any] = Field(default_factory=dict)


class JobSpec(_Model):
    """One job: a scene file (e.g. a repair scene), optionally with overrides."""

    name: JobName | None = None
    scene: Path
    set: dict[str, Any] = Field(default_factory=dict)


def _flatten(table: Any, prefix: str = "") -> Any:
    """Nested tables (``material = { youngs_modulus = 1 }``, or TOML's unquoted dotted keys) → key paths."""
    if not isinstance(table, dict):
        return table
    out: dict[str, Any] = {}
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict) and v:
            out.update(_flatten(v, key))
        else:
            out[key] = v
    return out


class BatchSpec(_Model):
    """A batch spec file: the jobs' scenes and overrides, and how failures are retried."""

    name: Name = "batch"
    retries: Annotated[int, Strict(), Field(ge=0, le=100)] = 1
    threads_per_job: PosInt | None = None
    base: BaseSpec | None = None
    set: dict[str, Any] = Field(default_factory=dict)
    grid: dict[str, Annotated[list[Any], Field(min_length=1)]] = Field(default_factory=dict)
    cases: list[CaseSpec] = Field(default_factory=list)
    jobs: list[JobSpec] = Field(default_factory=list)

    @model_validator(mode="before")
    @classmethod
    def _key_paths(cls, data: Any) -> Any:
        """Nested override tables become key paths (the values of a grid are its lists)."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        for key in ("set", "grid"):
            if isinstance(data.get(key), dict):
                data[key] = _flatten(data[key])
        for key in ("cases", "jobs"):
            entries = data.get(key)
            if isinstance(entries, list):
                data[key] = [
                    {**e, "set": _flatten(e["set"])} if isinstance(e, dict) and isinstance(e.get("set"), dict) else e
                    for e in entries
                ]
        return data

    @model_validator(mode="after")
    def _rules(self) -> BatchSpec:
        probs: list[tuple[str, str]] = []

        def check(where: str, keys: Any) -> None:
            for key in keys:
                try:
                    parse_key_path(key)
                except ValueError as exc:
                    probs.append((f"{where}.{json.dumps(key)}", str(exc)))

        check("set", self.set)
        check("grid", self.grid)
        for i, c in enumerate(self.cases):
            check(f"cases[{i}].set", c.set)
            if c.scene is None and self.base is None:
                probs.append((f"cases[{i}].scene", "required when the spec has no [base] scene"))
        for i, j in enumerate(self.jobs):
            check(f"jobs[{i}].set", j.set)
        if self.grid and self.base is None:
            probs.append(("base", "a [grid] needs a [base] table naming the scene it overrides (scene = ...)"))
        if not self.grid and not self.cases and not self.jobs:
            probs.append(("(top level)", "no jobs: give a [grid] over a [base] scene, [[cases]] or [[jobs]]"))
        if probs:
            raise rule_error(probs)
        return self


MODELS.update({m.__name__: m for m in (BatchSpec, BaseSpec, CaseSpec, JobSpec)})  # error paths name their keys


@dataclass
class BatchJob:
    """One run of a batch: its name (and folder), scene file, overrides, and the validated scene."""

    name: str
    scene_file: Path  # absolute
    overrides: dict[str, Any]  # the job's own overrides (key path → value as written), after the spec's common `set`
    scene: Scene
    scene_toml: str  # the resolved scene the job runs (every path absolute, every default filled in)
    origin: str  # where the spec defines it: "grid[3]", "cases[0]", "jobs[1]"
    explicit_name: bool = field(default=False, repr=False)


def load_batch_spec(path: str | Path) -> BatchSpec:
    """Read and validate a batch spec (TOML or JSON); SceneError names the file and the key."""
    p = Path(path)
    data = read_scene_data(p)
    if "name" not in data:
        data = {"name": p.stem, **data}
    try:
        return BatchSpec.model_validate(data)
    except ValidationError as err:
        raise SceneError(format_validation_error(err, str(p))) from err


def load_batch(path: str | Path) -> tuple[BatchSpec, list[BatchJob]]:
    """The spec and its jobs, every job's scene validated with its overrides applied (nothing is built)."""
    p = Path(path)
    spec = load_batch_spec(p)
    return spec, expand_jobs(spec, p)


def _absolute(p: Path, base: Path) -> Path:
    p = p.expanduser()
    return p if p.is_absolute() else (base / p).absolute()


def _resolve_value(parts: KeyPath, value: Any, spec_dir: Path) -> Any:
    """A relative file path given in the spec is relative to the spec's folder (``data:`` paths are kept)."""
    if isinstance(value, str) and value and not value.startswith(DATA_PREFIX) and is_path_field(parts):
        return str(_absolute(Path(value), spec_dir))
    return value


def _short_value(parts: KeyPath, v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:g}" if math.isfinite(v) else str(v)
    if isinstance(v, str):
        if is_path_field(parts) or "/" in v:
            stem = Path(v.removeprefix(DATA_PREFIX)).name
            return stem.split(".")[0] or stem
        return v
    return json.dumps(v, separators=(",", ":"), sort_keys=True, default=str)


def _safe(text: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._=+-]+", "_", text).strip("._-=+")
    return s[:90].rstrip("._-=+")


def _label(prefix: str, overrides: dict[str, Any]) -> str:
    """``youngs_modulus=1e+05_dhat=0.002`` (the last name of each key path; the whole path where two agree)."""
    parsed = {k: parse_key_path(k) for k in overrides}
    lasts = [next(p for p in reversed(parts) if isinstance(p, str)) for parts in parsed.values()]
    items = []
    for (key, parts), last in zip(parsed.items(), lasts, strict=True):
        short = last if lasts.count(last) == 1 else key
        items.append(f"{short}={_short_value(parts, overrides[key])}")
    return _safe("_".join(([prefix] if prefix else []) + items))


def _digest(scene_file: Path, overrides: dict[str, Any]) -> str:
    text = json.dumps([str(scene_file), overrides], sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def expand_jobs(spec: BatchSpec, spec_path: str | Path) -> list[BatchJob]:
    """Every job of ``spec`` (grid points, then cases, then jobs), validated; SceneError lists every problem."""
    src = str(spec_path)
    spec_dir = Path(spec_path).absolute().parent
    # (scene file, job-specific overrides, explicit name, origin)
    planned: list[tuple[Path, dict[str, Any], str | None, str]] = []
    if spec.grid:
        assert spec.base is not None
        base = _absolute(spec.base.scene, spec_dir)
        keys = list(spec.grid)
        for n, values in enumerate(itertools.product(*(spec.grid[k] for k in keys))):
            planned.append((base, dict(zip(keys, values, strict=True)), None, f"grid[{n}]"))
    for i, c in enumerate(spec.cases):
        case_scene = c.scene if c.scene is not None else spec.base.scene if spec.base is not None else None
        assert case_scene is not None
        planned.append((_absolute(case_scene, spec_dir), dict(c.set), c.name, f"cases[{i}]"))
    for i, j in enumerate(spec.jobs):
        planned.append((_absolute(j.scene, spec_dir), dict(j.set), j.name, f"jobs[{i}]"))

    # each scene file read and validated once, as itself: its own problems name the file, not a job
    raw: dict[Path, dict[str, Any]] = {}
    problems: list[str] = []
    for scene_file, *_ in planned:
        if scene_file in raw:
            continue
        try:
            load_scene(scene_file)
            data = read_scene_data(scene_file)
        except SceneError as exc:
            problems.append(str(exc))
            raw[scene_file] = {}
            continue
        raw[scene_file] = data if "name" in data else {"name": scene_file.stem, **data}
    if problems:
        raise SceneError(_problem_lines(problems, src))

    names = _names(planned, spec, src)
    jobs: list[BatchJob] = []
    for (scene_file, own, explicit, origin), name in zip(planned, names, strict=True):
        where = f"{src}: job {name} ({origin})"
        data = copy.deepcopy(raw[scene_file])
        bad = False
        for key, value in [*spec.set.items(), *own.items()]:
            parts = parse_key_path(key)
            try:
                apply_override(data, parts, _resolve_value(parts, value, spec_dir))
            except ValueError as exc:
                problems.append(f"{where}: {key}: {exc}")
                bad = True
        if bad:
            continue
        try:
            scene = scene_from_dict(data, base_dir=scene_file.parent, source=where)
        except SceneError as exc:
            problems.append(str(exc))
            continue
        jobs.append(BatchJob(name, scene_file, own, scene, dump_scene_toml(scene), origin, explicit is not None))
    if problems:
        raise SceneError(_problem_lines(problems, src))
    return jobs


def _names(planned: list[tuple[Path, dict[str, Any], str | None, str]], spec: BatchSpec, src: str) -> list[str]:
    """Deterministic, unique, file-safe job names: the case's own name, else one made from the overrides (with
    the scene's stem for a scene other than the base), and a short hash of scene and overrides where two agree."""
    base = spec.base.scene.stem if spec.base is not None else None
    labels: list[str] = []
    for scene_file, own, explicit, _ in planned:
        if explicit is not None:
            labels.append(explicit)
            continue
        prefix = "" if scene_file.stem == base else scene_file.stem
        labels.append(_label(prefix, own) or "base")
    explicit_names = [p[2] for p in planned if p[2] is not None]
    dup = sorted({n for n in explicit_names if explicit_names.count(n) > 1})
    if dup:
        raise SceneError(f"{src}: job name {dup[0]!r} is given to more than one case/job")
    names = []
    for label, (scene_file, own, explicit, _) in zip(labels, planned, strict=True):
        if explicit is None and labels.count(label) > 1:
            label = f"{label[:80]}-{_digest(scene_file, own)}"
        names.append(label)
    seen: dict[str, str] = {}
    for name, (_, _, _, origin) in zip(names, planned, strict=True):
        if name in seen:
            raise SceneError(
                f"{src}: {origin} and {seen[name]} are the same job (the same scene and overrides, name {name!r})"
            )
        seen[name] = origin
    return names
