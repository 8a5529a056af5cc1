"""Shared pieces of the scene schema: strict scalar/vector types, the base model and rule errors."""

from __future__ import annotations

import math
import types
import typing
from typing import Annotated, Any, Union

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from idp.errors import SceneError

# ---------------------------------------------------------------------------------------------
# Scalar and vector types (strict: TOML/JSON `true` or "10" is never silently a number)

# Integers are 64-bit, as in the TOML specification (Python's parsers read any size; a vertex index of 10^20
# reached numpy as an OverflowError).
I64 = 2**63 - 1
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict(), Field(ge=-I64 - 1, le=I64)]
Bool = Annotated[bool, Strict()]
PosFloat = Annotated[float, Strict(), Field(gt=0)]
PosInt = Annotated[int, Strict(), Field(ge=1, le=I64)]
NonNegInt = Annotated[int, Strict(), Field(ge=0, le=I64)]
Name = Annotated[str, Field(min_length=1)]


def _fixed_length(n: int) -> AfterValidator:
    """Validator requiring a list of exactly ``n`` entries."""

    def check(v: list[Any]) -> list[Any]:
        if len(v) != n:
            raise PydanticCustomError(
                "vector_length",
                "must have {expected} entries (got {actual})",
                {"expected": n, "actual": len(v)},
            )
        return v

    return AfterValidator(check)


Vec2 = Annotated[list[Float], _fixed_length(2)]
Vec3 = Annotated[list[Float], _fixed_length(3)]
PosVec3 = Annotated[list[PosFloat], _fixed_length(3)]
Res2 = Annotated[list[PosInt], _fixed_length(2)]
Res3 = Annotated[list[PosInt], _fixed_length(3)]
Scale = Float | list[Float]


def rule_error(problems: list[tuple[str, str]]) -> PydanticCustomError:
    """A cross-field error; each problem is ``(sub-path relative to the model, message)``."""
    return PydanticCustomError(
        "scene_rule",
        "{message}",
        {
            "message": "; ".join(f"{p}: {m}" if p else m for p, m in problems),
            "problems": [[p, m] for p, m in problems],
        },
    )


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _auto_or_number(v: Any, lowest: float, inclusive: bool, note: str = "") -> Any:
    """Accept the string "auto" or a finite number above ``lowest`` (or equal to it when ``inclusive``), as float."""
    if v == "auto" and isinstance(v, str):
        return v
    bound = f'must be "auto" or a number {">=" if inclusive else ">"} {lowest:g}{note}'
    if _is_number(v):
        if not (math.isfinite(v) and (v >= lowest if inclusive else v > lowest)):
            raise ValueError(f"{bound} (got {v})")
        return float(v)
    raise ValueError(f"{bound} (got {v!r})")


def _check_scale(v: Any) -> Any:
    """Accept a positive number or a list of positive numbers (clear single message otherwise)."""
    if _is_number(v):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"must be > 0 (got {v})")
        return float(v)
    if isinstance(v, (list, tuple)):
        if len(v) == 0:
            raise ValueError("must be a number or a non-empty list of numbers")
        for i, x in enumerate(v):
            if not _is_number(x):
                raise ValueError(f"entry [{i}] must be a number (got {x!r})")
            if not (math.isfinite(x) and x > 0):
                raise ValueError(f"entry [{i}] must be > 0 (got {x})")
        return [float(x) for x in v]
    raise ValueError(f"must be a positive number or a list of positive numbers (got {v!r})")


def _check_box(lo: list[float], hi: list[float], strict: bool) -> list[tuple[str, str]]:
    """Problems with a box given by its corners (per-axis lo < hi, or lo <= hi)."""
    if len(lo) != len(hi):
        return [("hi", f"must have as many entries as lo ({len(lo)}, got {len(hi)})")]
    bad = [i for i in range(len(lo)) if (lo[i] >= hi[i] if strict else lo[i] > hi[i])]
    if bad:
        op = "<" if strict else "<="
        return [("hi", f"need lo {op} hi on every axis (axis {bad[0]}: lo={lo[bad[0]]}, hi={hi[bad[0]]})")]
    return []


class _Model(BaseModel):
    """Base: unknown keys are errors, floats must be finite; construction raises SceneError."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def __init__(self, /, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as err:
            from idp.scene.load import format_validation_error

            raise SceneError(format_validation_error(err, type(self).__name__)) from err

    # Validation (model_validate, nested models) must keep pydantic's own path and not call this
    # wrapper; the flag tells pydantic the override behaves like BaseModel.__init__.
    __init__.__pydantic_base_init__ = True  # type: ignore[attr-defined]


def check_corner_box(box: list[list[float]]) -> None:
    """A selection box given as ``[lo, hi]`` (lo <= hi per axis); raises the rule error naming ``box``."""
    if len(box) != 2:
        raise rule_error([("box", f"must be two corners [lo, hi] (got {len(box)} entries)")])
    probs = _check_box(box[0], box[1], strict=False)
    if probs:
        raise rule_error([("box", probs[0][1])])


class Rotation(_Model):
    """Rotation about the origin; ``axis`` only in 3D (2D rotates in the plane)."""

    axis: list[Float] | None = None
    degrees: Float

    @field_validator("axis")
    @classmethod
    def _nonzero(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and not any(x != 0 for x in v):
            raise ValueError("must be non-zero")
        return v


def unwrap_type(tp: Any) -> Any:
    """A field annotation without Annotated and Optional (a union of several non-None types is returned as is):
    what the scene loader's error paths and the batch's key-path overrides walk through."""
    while True:
        origin = typing.get_origin(tp)
        if origin is typing.Annotated:
            tp = typing.get_args(tp)[0]
        elif origin is Union or origin is getattr(types, "UnionType", Union):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) != 1:
                return tp
            tp = args[0]
        else:
            return tp
