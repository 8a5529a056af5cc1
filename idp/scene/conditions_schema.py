"""Scene-file models of the time-varying conditions (paper §4.3, §4.5): handles, motions, Dirichlet settings,
kinematic obstacles, rest-shape scripts, material stages and plasticity.

::

    [[objects.handles]]
    name = "left_cap"
    select = { box = [[0, 0, 0], [0.06, 1, 1]], relative = true }   # or sphere / indices
    motion = { type = "rotate", axis = [0, 0, 1], center = [0, 0.06, 0], degrees_per_second = -90 }
    end = 26            # moves during steps 1..26, then holds its last targets until `release` (or the end)

Obstacles move as a whole with ``motion`` (kinematic obstacles). Vector lengths are checked against the
scene's ``dim`` by :class:`idp.scene.schema.Scene`.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, Strict, model_validator

from idp.scene.schema_base import (
    Bool,
    Float,
    Name,
    NonNegInt,
    PosFloat,
    PosInt,
    Scale,
    _Model,
    check_corner_box,
    rule_error,
)


class SphereSpec(_Model):
    """Vertices within ``radius`` of ``center`` (bbox-relative centre when the selection is relative)."""

    center: list[Float]
    radius: PosFloat


class SelectionSpec(_Model):
    """Exactly one of ``box`` [lo, hi], ``sphere``, ``indices`` (object-local vertex ids) or ``group`` (a named
    vertex group of the mesh file: a point set, or an integer/bool point field whose nonzero entries are in).

    ``relative``: box corners / sphere centre are fractions of the object's bounding box (0 = min, 1 = max).
    ``exclude``: a second selection whose vertices are taken out (e.g. the left half of a sheet minus a disk
    about its centre = the left half of its rim); its own ``relative`` refers to the same bounding box."""

    box: list[list[Float]] | None = None
    sphere: SphereSpec | None = None
    indices: Annotated[list[NonNegInt], Field(min_length=1)] | None = None
    group: Name | None = None
    relative: Bool = False
    exclude: SelectionSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> SelectionSpec:
        given = [k for k in ("box", "sphere", "indices", "group") if getattr(self, k) is not None]
        if len(given) != 1:
            raise rule_error(
                [("", f"give exactly one of `box`, `sphere`, `indices` or `group` (got {given or 'none'})")]
            )
        if (self.indices is not None or self.group is not None) and self.relative:
            raise rule_error([("relative", "only applies to `box` and `sphere`")])
        if self.box is not None:
            check_corner_box(self.box)
        return self


class RotationSpec(_Model):
    """A rotation for keyframes: ``degrees`` about ``axis`` (3D; omitted in 2D)."""

    axis: list[Float] | None = None
    degrees: Float = 0.0


class KeyframeSpec(_Model):
    """Transform of the handle at ``step`` steps after it starts: scale, then rotate, about ``center``, then
    translate."""

    step: NonNegInt
    translate: list[Float] | None = None
    rotate: RotationSpec | None = None
    scale: Scale = 1.0


MOTION_TYPES = ("fixed", "translate", "rotate", "scale", "keyframes", "targets", "roll")


class MotionSpec(_Model):
    """How a handle (or a kinematic obstacle) moves; rates are per second of scene time (one step = √h).

    - ``fixed``: stays where it was when the handle started;
    - ``translate``: ``velocity``;
    - ``rotate``: ``degrees_per_second`` about ``axis`` (3D) through ``center``;
    - ``scale``: factor 1 + ``rate``·t (scalar or per axis) about ``center``; ``law = "exponential"``: e^{rate·t},
      the same fraction per unit time (the authors' ``scaleVel = −0.1`` per step is rate = ln(0.9)/√h);
      ``about = "selection"`` instead of ``center``: about the centre of the handle's bounding box (where it
      started, or each step's with ``incremental``), as the authors' ``scaleVel`` does;
    - ``incremental = true`` (translate, rotate, scale): each step's targets are one step of the motion applied
      to where the vertices are at the step's start, so a blocked handle is not pushed further and further;
    - ``keyframes``: ``keyframes`` (at least two, increasing ``step``), ``interpolation`` linear or smooth,
      about ``center``;
    - ``targets``: final positions reached in ``quota`` steps (§4.3), either ``offset`` (added to the
      start positions) or ``file`` (.npy/.npz: (k, d) final targets, or (F, k, d) one frame per step);
    - ``roll`` (3D): rolls a strip up like a carpet from its start edge at ``center``: ``speed`` (length per
      second) of it along ``direction`` is wound onto the spiral r = ``pitch``·φ about ``axis``; the roll rises
      on the ``axis`` × ``direction`` side (:class:`idp.stepper.motions.Roll`; the authors' rose).
    """

    type: Literal["fixed", "translate", "rotate", "scale", "keyframes", "targets", "roll"] = "fixed"
    velocity: list[Float] | None = None
    degrees_per_second: Float | None = None
    axis: list[Float] | None = None
    center: list[Float] | None = None
    rate: Scale | None = None
    law: Literal["linear", "exponential"] = "linear"
    # each step's targets: one step of the motion applied to where the vertices are (not to where they started)
    incremental: Bool = False
    keyframes: list[KeyframeSpec] | None = None
    interpolation: Literal["linear", "smooth"] = "linear"
    offset: list[Float] | None = None
    file: Path | None = None
    quota: PosInt = 1
    direction: list[Float] | None = None  # roll: the strip's length direction
    speed: PosFloat | None = None  # roll: length wound per second
    pitch: PosFloat | None = None  # roll: r = pitch·φ (layers 2π·pitch apart)
    about: Literal["center", "selection"] = "center"  # scale: about `center`, or the selection's box centre

    @model_validator(mode="after")
    def _fields(self) -> MotionSpec:
        need = {
            "fixed": (),
            "translate": ("velocity",),
            "rotate": ("degrees_per_second",),
            "scale": ("rate",),
            "keyframes": ("keyframes",),
            "targets": (),
            "roll": ("axis", "direction", "center", "speed", "pitch"),
        }[self.type]
        probs = [(k, f"required for type = {self.type!r}") for k in need if getattr(self, k) is None]
        allowed = set(need) | {"interpolation", "quota"}
        allowed |= {
            "rotate": {"axis", "center"},
            "scale": {"center"},
            "keyframes": {"center"},
            "targets": {"offset", "file"},
        }.get(self.type, set())
        for k in (
            "velocity",
            "degrees_per_second",
            "axis",
            "center",
            "rate",
            "keyframes",
            "offset",
            "file",
            "direction",
            "speed",
            "pitch",
        ):
            if getattr(self, k) is not None and k not in allowed:
                probs.append((k, f"not used by type = {self.type!r}"))
        if self.type == "targets" and (self.offset is None) == (self.file is None):
            probs.append(("", "type = 'targets' needs exactly one of `offset` or `file`"))
        if self.incremental and self.type in ("targets", "keyframes", "fixed", "roll"):
            probs.append(("incremental", f"not used by type = {self.type!r} (its targets are positions, not rates)"))
        if self.about == "selection" and (self.type != "scale" or self.center is not None):
            probs.append(("about", "'selection' is for type = 'scale' without a `center`"))
        if self.type != "scale" and self.law != "linear":
            probs.append(("law", "only used by type = 'scale'"))
        if self.type != "targets" and self.quota != 1:
            probs.append(("quota", "only used by type = 'targets'"))
        if self.keyframes is not None:
            if len(self.keyframes) < 2:
                probs.append(("keyframes", "needs at least two keyframes"))
            steps = [k.step for k in self.keyframes]
            if any(b <= a for a, b in itertools.pairwise(steps)):
                probs.append(("keyframes", f"steps must increase strictly (got {steps})"))
        if probs:
            raise rule_error(probs)
        return self


class HandleSpec(_Model):
    """A handle: a vertex selection of this object driven by a motion during steps ``start``+1 … ``end``,
    holding its last targets after ``end``, and letting its vertices go after step ``release``.

    ``select_on = "current"`` selects on the shape at step ``start`` (e.g. a handle added on a deformed shape)."""

    name: Name
    select: SelectionSpec
    motion: MotionSpec = Field(default_factory=MotionSpec)
    start: NonNegInt = 0
    end: PosInt | None = None
    release: PosInt | None = None
    select_on: Literal["rest", "current"] = "rest"

    @model_validator(mode="after")
    def _range(self) -> HandleSpec:
        probs = []
        if self.end is not None and self.end <= self.start:
            probs.append(("end", f"must be > start ({self.start}), got {self.end}"))
        if self.release is not None:
            if self.release <= self.start:
                probs.append(("release", f"must be > start ({self.start}), got {self.release}"))
            elif self.end is not None and self.release < self.end:
                probs.append(("release", f"must be >= end ({self.end}), got {self.release}"))
        if probs:
            raise rule_error(probs)
        return self


class KinematicSpec(_Model):
    """Motion of a whole obstacle (a kinematic rigid tool) during steps ``start``+1 … ``end``, then held."""

    motion: MotionSpec
    start: NonNegInt = 0
    end: PosInt | None = None

    @model_validator(mode="after")
    def _range(self) -> KinematicSpec:
        if self.end is not None and self.end <= self.start:
            raise rule_error([("end", f"must be > start ({self.start}), got {self.end}")])
        if self.motion.type == "targets" and self.motion.file is not None:
            raise rule_error([("motion.file", "per-vertex target files are for handles, not whole obstacles")])
        return self


class DirichletConfig(_Model):
    """§4.3 boundary-condition settings: when a bound vertex counts as on target, the penalty κ_B, and what
    a step that ends with unmet targets does."""

    tolerance: PosFloat = 1e-2  # × d̂ (or absolute with tolerance_mode = "absolute")
    tolerance_mode: Literal["dhat", "absolute"] = "dhat"
    kappa_initial: PosFloat = 1e4
    max_doublings: Annotated[int, Strict(), Field(ge=0, le=60)] = 24
    # stop pushing a handle that contact holds back (a doubling of κ_B that gains < 10 % and less than the one
    # before; 30 CCD-cut iterates in contact without 10 % progress) instead of crushing the gap; false: the
    # paper's rule alone, κ_B doubles until the targets are met or it reaches 2^max_doublings × kappa_initial
    detect_blocked: Bool = True
    on_unmet: Literal["warn", "error"] = "warn"
    # "total_progress": also met once the bound vertices together have come met_progress of the way
    # (1 − √(Σ‖x − x̃‖² / Σ‖x⁰ − x̃‖²)), then held where they are: the authors' code's rule
    met_rule: Literal["each_vertex", "total_progress"] = "each_vertex"
    met_progress: Annotated[float, Strict(), Field(gt=0, lt=1)] = 0.99


class PlasticitySpec(_Model):
    """Von Mises plasticity (paper §4.5): the classical von Mises ``yield_stress`` σ_Y (uniaxial, stress units
    like Young's modulus; the engine's Frobenius-norm radius is √(2/3)·σ_Y) and linear isotropic ``hardening``
    H; the return mapping runs at the start of every step."""

    yield_stress: Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]
    hardening: Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)] = 0.0


class MaterialStageSpec(_Model):
    """From step ``start`` + 1 on, the body's Young's modulus and Poisson ratio (paper §7.5 stiffness stages)."""

    start: NonNegInt
    youngs_modulus: PosFloat
    poisson_ratio: Annotated[float, Field(gt=-1, lt=0.5)] = 0.4


class RestScriptSpec(_Model):
    """A rest-shape script (paper §4.5 "Shape").

    - ``type = "scale"``: during steps ``start``+1 … ``end`` the rest shape of the elements in ``region``
      (elements whose centroid the selection picks; all when omitted) scales by 1 + ``rate``·steps (per axis);
    - ``type = "bake"``: at the end of step ``step`` the current shape becomes the rest shape."""

    type: Literal["scale", "bake"]
    start: NonNegInt = 0
    end: PosInt | None = None
    rate: Scale | None = None
    region: SelectionSpec | None = None
    step: PosInt | None = None

    @model_validator(mode="after")
    def _fields(self) -> RestScriptSpec:
        probs = []
        if self.type == "scale":
            if self.rate is None:
                probs.append(("rate", "required for type = 'scale'"))
            if self.end is None:
                probs.append(("end", "required for type = 'scale'"))
            elif self.end <= self.start:
                probs.append(("end", f"must be > start ({self.start}), got {self.end}"))
            elif self.rate is not None:
                rates = self.rate if isinstance(self.rate, list) else [self.rate]
                final = [1.0 + r * (self.end - self.start) for r in rates]
                if min(final) <= 0:
                    probs.append(("rate", f"makes the scale factor {min(final):g} <= 0 by step {self.end}"))
            if self.step is not None:
                probs.append(("step", "only used by type = 'bake'"))
        else:
            if self.step is None:
                probs.append(("step", "required for type = 'bake'"))
            for k in ("rate", "region", "end"):
                if getattr(self, k) is not None:
                    probs.append((k, "only used by type = 'scale'"))
        if probs:
            raise rule_error(probs)
        return self
