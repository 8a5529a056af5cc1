"""Instancing (paper §7.5): copies of one object, each its own body, placed by explicit or generated transforms.

An object with ``instances`` is replaced, when the scene is validated, by N objects named ``{name}_0`` ...
``{name}_{N-1}``; each is the object (mesh, material, handles, ...) with its own ``instance_transform``, a
``{matrix, translate}`` affine map applied AFTER the object's own placement (``scale``, then ``rotate`` about
the origin, then ``translate``). A copy's transform is itself: scale, rotate about the origin, translate. The
expanded objects have no ``instances``, so a resolved scene (``scene.resolved.toml``) lists every copy with its
transform and reloads to the same layout without expanding again.

Generators (give exactly one in ``instances``):

- ``transforms``: explicit copies, each ``{ scale, rotate = [{axis, degrees}, ...], translate }``;
- ``grid``: ``{ counts = [nx, ny(, nz)], spacing, origin }``, copy ``i + nx (j + ny l)`` moved by
  ``origin + (i, j, l) * spacing`` (x fastest);
- ``ring`` (or ``rings``, a list whose copies follow one another): ``{ count, radius, center, axis,
  start_degrees, face_center, rotate_offset_degrees }``, see :func:`idp.mesh.layout.ring_transforms`. The
  angle ``phi_k = start_degrees + k * 360 / count`` runs right-handed about ``axis`` (default +y) from the
  direction ``u`` of :func:`idp.mesh.layout.ring_basis` (x for an axis along ±y or ±z); copy ``k`` goes to
  ``center + radius (cos phi u + sin phi (axis × u))`` and turns about ``axis`` by
  ``rotate_offset_degrees + phi`` (``face_center = true``, keeping its orientation relative to the centre)
  or by ``rotate_offset_degrees`` only. The paper's rhododendron rings ("rotated about +y by (−90° − φ),
  translated to (r cos φ, 0, r sin φ)") are ``axis = [0, -1, 0], rotate_offset_degrees = 90``: about −y the
  angle runs from x towards +z, and turning by 90° + φ about −y is turning by −90° − φ about +y. In 2D there
  is no axis: ``center + radius (cos phi, sin phi)``, turned counter-clockwise by the same angle;
- ``random``: ``{ count, seed, translate_lo, translate_hi, rotate_axis, degrees_lo, degrees_hi, scale_lo,
  scale_hi }``, drawn with ``numpy.random.default_rng(seed)`` (:func:`idp.mesh.layout.random_transforms`):
  the same seed gives the same layout bit for bit; a random axis per copy when ``rotate_axis`` is left out
  (3D).

Copies that start intersecting are refused when the scene is built (the error names the two copies); two
copies placed identically are refused here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from pydantic import Field, field_validator, model_validator

from idp.errors import MeshError
from idp.mesh.layout import explicit_transform, grid_transforms, random_transforms, ring_transforms
from idp.scene.schema_base import (
    Bool,
    Float,
    NonNegInt,
    PosFloat,
    PosInt,
    Rotation,
    Scale,
    _check_box,
    _check_scale,
    _Model,
    rule_error,
)

if TYPE_CHECKING:
    from idp.scene.schema import SceneObject

#: most copies one object may make (each is a scene object with its own mesh arrays)
MAX_INSTANCES = 10_000

GENERATOR_KEYS = ("transforms", "grid", "ring", "rings", "random")


class TransformSpec(_Model):
    """One explicit copy: scale, then rotations in order about the origin, then translate."""

    scale: Scale = 1.0
    rotate: list[Rotation] = Field(default_factory=list)
    translate: list[Float] | None = None

    @field_validator("scale", mode="before")
    @classmethod
    def _scale(cls, v: Any) -> Any:
        return _check_scale(v)


class GridSpec(_Model):
    """Copies on a grid: ``counts`` per axis, ``spacing`` apart, copy 0 moved by ``origin`` (default zeros)."""

    counts: list[PosInt]
    spacing: list[PosFloat]
    origin: list[Float] | None = None


class RingSpec(_Model):
    """Copies on a circle about ``axis`` through ``center`` (see the module docstring for the convention)."""

    count: PosInt
    radius: PosFloat
    center: list[Float] | None = None  # default: the origin
    axis: list[Float] | None = None  # 3D only; default [0, 1, 0]
    start_degrees: Float = 0.0
    face_center: Bool = True
    rotate_offset_degrees: Float = 0.0


class RandomSpec(_Model):
    """Seeded random copies: translation uniform in a box, rotation and scale factor uniform in ranges."""

    count: PosInt
    seed: NonNegInt
    translate_lo: list[Float]
    translate_hi: list[Float]
    rotate_axis: list[Float] | None = None  # 3D: a random axis per copy when left out; 2D: omitted
    degrees_lo: Float = 0.0
    degrees_hi: Float = 360.0
    scale_lo: PosFloat = 1.0
    scale_hi: PosFloat = 1.0

    @model_validator(mode="after")
    def _ranges(self) -> RandomSpec:
        probs = _check_box(self.translate_lo, self.translate_hi, strict=False)
        probs = [("translate_hi", m.replace("lo", "translate_lo").replace("hi", "translate_hi")) for _, m in probs]
        if self.degrees_lo > self.degrees_hi:
            probs.append(("degrees_hi", f"must be >= degrees_lo ({self.degrees_lo}, got {self.degrees_hi})"))
        if self.scale_lo > self.scale_hi:
            probs.append(("scale_hi", f"must be >= scale_lo ({self.scale_lo}, got {self.scale_hi})"))
        if probs:
            raise rule_error(probs)
        return self


class InstancesSpec(_Model):
    """Copies of an object, each its own body ``{name}_{k}``: give exactly one generator."""

    transforms: Annotated[list[TransformSpec], Field(min_length=1)] | None = None
    grid: GridSpec | None = None
    ring: RingSpec | None = None
    rings: Annotated[list[RingSpec], Field(min_length=1)] | None = None
    random: RandomSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> InstancesSpec:
        given = [k for k in GENERATOR_KEYS if getattr(self, k) is not None]
        if not given:
            raise rule_error([("", f"give one of: {', '.join(GENERATOR_KEYS)}")])
        if len(given) > 1:
            raise rule_error([(given[1], f"give exactly one of: {', '.join(GENERATOR_KEYS)} ({given[0]} is given)")])
        return self

    def count(self) -> int:
        """How many copies the spec makes."""
        if self.transforms is not None:
            return len(self.transforms)
        if self.grid is not None:
            return int(np.prod([float(c) for c in self.grid.counts]))  # float: no overflow on huge counts
        if self.ring is not None:
            return self.ring.count
        if self.rings is not None:
            return sum(r.count for r in self.rings)
        assert self.random is not None
        return self.random.count


class InstanceTransform(_Model):
    """The affine map of one copy, applied after the object's own placement: ``x -> matrix @ x + translate``."""

    matrix: list[list[Float]]
    translate: list[Float]

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.matrix, dtype=np.float64), np.asarray(self.translate, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Dimension checks and expansion (called by Scene's validator)


def _vec(path: str, v: Sequence[float] | None, d: int, probs: list[tuple[str, str]]) -> bool:
    if v is not None and len(v) != d:
        probs.append((path, f"must have {d} entries for dim = {d} (got {len(v)})"))
        return False
    return True


def _axis(path: str, v: list[float] | None, d: int, probs: list[tuple[str, str]], required: bool) -> None:
    if d == 2 and v is not None:
        probs.append((path, "must be omitted in 2D (rotation is in the plane)"))
    elif d == 3 and v is None and required:
        probs.append((path, "required in 3D"))
    elif v is not None and _vec(path, v, d, probs) and not any(x != 0 for x in v):
        probs.append((path, "must be non-zero"))


def _check_ring(p: str, r: RingSpec, d: int, probs: list[tuple[str, str]]) -> None:
    _vec(f"{p}.center", r.center, d, probs)
    _axis(f"{p}.axis", r.axis, d, probs, required=False)


def _check_spec(p: str, spec: InstancesSpec, d: int, probs: list[tuple[str, str]]) -> None:
    """Dimension checks of an instances spec at key path ``p`` (``objects[i].instances``)."""
    if spec.transforms is not None:
        for j, t in enumerate(spec.transforms):
            q = f"{p}.transforms[{j}]"
            _vec(f"{q}.translate", t.translate, d, probs)
            if isinstance(t.scale, list):
                _vec(f"{q}.scale", t.scale, d, probs)
            for m, rot in enumerate(t.rotate):
                _axis(f"{q}.rotate[{m}].axis", rot.axis, d, probs, required=True)
    if spec.grid is not None:
        g = spec.grid
        _vec(f"{p}.grid.counts", g.counts, d, probs)
        _vec(f"{p}.grid.spacing", g.spacing, d, probs)
        _vec(f"{p}.grid.origin", g.origin, d, probs)
    if spec.ring is not None:
        _check_ring(f"{p}.ring", spec.ring, d, probs)
    for j, r in enumerate(spec.rings or []):
        _check_ring(f"{p}.rings[{j}]", r, d, probs)
    if spec.random is not None:
        rd = spec.random
        _vec(f"{p}.random.translate_lo", rd.translate_lo, d, probs)
        _vec(f"{p}.random.translate_hi", rd.translate_hi, d, probs)
        _axis(f"{p}.random.rotate_axis", rd.rotate_axis, d, probs, required=False)
    n = spec.count()
    if n > MAX_INSTANCES:
        key = next(k for k in GENERATOR_KEYS if getattr(spec, k) is not None)
        probs.append((f"{p}.{key}", f"makes {n:.6g} copies, more than {MAX_INSTANCES}"))


def _check_transform(p: str, t: InstanceTransform, d: int, probs: list[tuple[str, str]]) -> None:
    if len(t.matrix) != d or any(len(row) != d for row in t.matrix):
        probs.append((f"{p}.matrix", f"must be {d} rows of {d} numbers for dim = {d}"))
    elif not np.linalg.det(np.asarray(t.matrix, dtype=np.float64)) > 0:  # NaN (overflow) too
        probs.append((f"{p}.matrix", "must have a positive determinant (a mirror or a collapse inverts elements)"))
    _vec(f"{p}.translate", t.translate, d, probs)


def _ring_arrays(r: RingSpec, d: int) -> tuple[np.ndarray, np.ndarray]:
    return ring_transforms(
        r.count,
        r.radius,
        r.center if r.center is not None else [0.0] * d,
        r.axis,
        r.start_degrees,
        r.face_center,
        r.rotate_offset_degrees,
    )


def instance_arrays(spec: InstancesSpec, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``(linear (N, d, d), translate (N, d))`` of every copy a (dimension-checked) spec makes, in order."""
    if spec.transforms is not None:
        pairs = [
            explicit_transform(d, t.scale, [(r.axis, r.degrees) for r in t.rotate], t.translate)
            for t in spec.transforms
        ]
        return np.stack([a for a, _ in pairs]), np.stack([b for _, b in pairs])
    if spec.grid is not None:
        return grid_transforms(spec.grid.counts, spec.grid.spacing, spec.grid.origin)
    if spec.ring is not None:
        return _ring_arrays(spec.ring, d)
    if spec.rings is not None:
        parts = [_ring_arrays(r, d) for r in spec.rings]
        return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])
    rd = spec.random
    assert rd is not None
    return random_transforms(
        rd.count,
        rd.seed,
        rd.translate_lo,
        rd.translate_hi,
        rd.rotate_axis,
        rd.degrees_lo,
        rd.degrees_hi,
        rd.scale_lo,
        rd.scale_hi,
    )


def _same_placement(linear: np.ndarray, translate: np.ndarray) -> tuple[int, int] | None:
    """Two copies whose transforms agree (to ~1e-9 of their size), or None."""
    flat = np.concatenate([linear.reshape(len(linear), -1), translate], axis=1)
    size = max(1.0, float(np.abs(flat).max(initial=0.0)))
    seen: dict[bytes, int] = {}
    for k, row in enumerate(np.round(flat / size, 9) + 0.0):  # + 0.0: -0.0 and 0.0 alike
        key = row.tobytes()
        if key in seen:
            return seen[key], k
        seen[key] = k
    return None


def expand_instances(objects: list[SceneObject], d: int) -> tuple[list[SceneObject], list[tuple[str, str]]]:
    """Every object with ``instances`` replaced by its copies ``{name}_{k}`` (each with ``instance_transform``
    and no ``instances``), in place of the object; and the problems found (key paths in the file's numbering).
    With problems, the objects are returned unchanged."""
    probs: list[tuple[str, str]] = []
    for i, ob in enumerate(objects):
        if ob.instance_transform is not None:
            _check_transform(f"objects[{i}].instance_transform", ob.instance_transform, d, probs)
            if ob.instances is not None:
                probs.append((f"objects[{i}].instance_transform", "give either `instances` or one transform"))
        if ob.instances is not None:
            _check_spec(f"objects[{i}].instances", ob.instances, d, probs)
    if probs or all(ob.instances is None for ob in objects):
        return objects, probs
    owner = {ob.name: f"objects[{i}]" for i, ob in enumerate(objects) if ob.instances is None}
    out: list[SceneObject] = []
    for i, ob in enumerate(objects):
        if ob.instances is None:
            out.append(ob)
            continue
        p = f"objects[{i}].instances"
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                linear, translate = instance_arrays(ob.instances, d)
                good = np.all(np.isfinite(translate)) and np.all(np.linalg.det(linear) > 0)
        except (OverflowError, ValueError, MeshError) as exc:  # ranges too wide for the generator
            probs.append((p, f"cannot make the copies' transforms ({exc})"))
            continue
        if not good:
            probs.append((p, "makes a transform that is not finite or not invertible (numbers too large)"))
            continue
        same = _same_placement(linear, translate)
        if same is not None:
            probs.append((p, f"copies {ob.name}_{same[0]} and {ob.name}_{same[1]} are placed identically"))
        for k in range(len(linear)):
            name = f"{ob.name}_{k}"
            if name in owner:
                probs.append((p, f"copy name '{name}' is already used by {owner[name]}; rename one of them"))
                break
            owner[name] = f"{p} (copy {k})"
            transform = InstanceTransform(matrix=linear[k].tolist(), translate=translate[k].tolist())
            copy = ob.model_copy(deep=True)
            copy.name, copy.instances, copy.instance_transform = name, None, transform
            out.append(copy)
    if probs:
        return objects, probs
    return out, probs
