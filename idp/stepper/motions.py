"""Scripted motions of handles and kinematic obstacles (paper §4.5 "Handles").

A motion maps the positions X (k, d) a handle had when it started acting and the time t ≥ 0 since then to
that step's target positions. Time is scene time: one artificial step lasts √h (the frame time the writers
record), so the authors' rates per second carry over (the bar's caps at −90°/s turn 3.6° per step with
h = 0.04²). All motions are pure functions of (X, t): a resumed run recomputes the same targets.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from idp.mesh.placement import rotation_matrix, rotation_matrix_2d


def _rotation(axis: np.ndarray | None, degrees: float, dim: int) -> np.ndarray:
    if dim == 2:
        return rotation_matrix_2d(degrees)
    if axis is None:  # (iterating None raised this TypeError before)
        raise TypeError("a 3D rotation needs an axis")
    return rotation_matrix(tuple(float(a) for a in axis), degrees)


class Motion:
    """Base class: ``targets(X, t)`` → (k, d) positions."""

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        raise NotImplementedError

    def check_count(self, k: int) -> None:
        """Raise ValueError when the motion carries per-vertex data for a different number of vertices."""


@dataclass
class Fixed(Motion):
    """The handle stays where it was when it started."""

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        return X


@dataclass
class Translate(Motion):
    """X + v·t."""

    velocity: np.ndarray

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        return X + np.asarray(self.velocity, dtype=float) * t


@dataclass
class Rotate(Motion):
    """Rotation by ω·t (degrees per second) about ``axis`` (3D; 2D rotates in the plane) through ``center``."""

    degrees_per_second: float
    center: np.ndarray | float  # 0.0: the origin
    axis: np.ndarray | None = None

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        c = np.asarray(self.center, dtype=float)
        R = _rotation(self.axis, self.degrees_per_second * t, X.shape[1])
        return (X - c) @ R.T + c


@dataclass
class Scale(Motion):
    """Scaling about ``center`` per axis by 1 + rate·t (``law = "linear"``) or e^{rate·t} (``"exponential"``: a
    fixed fraction per unit time, the reference code's per-step ``scaleVel``); rate a scalar or per axis."""

    rate: np.ndarray
    center: np.ndarray | float  # 0.0: the origin
    law: str = "linear"

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        c = np.asarray(self.center, dtype=float)
        r = np.asarray(self.rate, dtype=float)
        f = np.exp(r * t) if self.law == "exponential" else 1.0 + r * t
        if np.any(f <= 0):
            raise ValueError(f"scale motion reached a non-positive factor {f} at t = {t:g}")
        return (X - c) * f + c


@dataclass
class Keyframe:
    """A rigid-plus-scale transform at time ``time``: x = R (s (X − c)) + c + translate."""

    time: float
    translate: np.ndarray | float  # 0.0: no translation
    rotation_vector: np.ndarray  # 3D: axis · radians; 2D: (radians,)
    scale: np.ndarray


@dataclass
class Keyframes(Motion):
    """Piecewise interpolation between keyframes (linear, or ``smooth``: smoothstep in each interval).

    Translation, scale and rotation vector are interpolated; before the first key the first holds, after
    the last the last holds."""

    keys: list[Keyframe]
    center: np.ndarray | float  # 0.0: the origin
    smooth: bool = False

    def _at(self, t: float) -> tuple[np.ndarray | float, np.ndarray, np.ndarray]:
        ks = self.keys
        if t <= ks[0].time:
            k = ks[0]
            return k.translate, k.rotation_vector, k.scale
        for a, b in itertools.pairwise(ks):
            if t <= b.time:
                u = (t - a.time) / (b.time - a.time)
                if self.smooth:
                    u = u * u * (3.0 - 2.0 * u)
                return (
                    (1 - u) * a.translate + u * b.translate,
                    (1 - u) * a.rotation_vector + u * b.rotation_vector,
                    (1 - u) * a.scale + u * b.scale,
                )
        k = ks[-1]
        return k.translate, k.rotation_vector, k.scale

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        tr, rv, sc = self._at(t)
        d = X.shape[1]
        c = np.asarray(self.center, dtype=float)
        if d == 2:
            R = rotation_matrix_2d(math.degrees(float(rv[0])))
        else:
            ang = float(np.linalg.norm(rv))
            R = np.eye(3) if ang == 0.0 else rotation_matrix(tuple(rv / ang), math.degrees(ang))
        return ((X - c) * sc) @ R.T + c + tr


@dataclass
class PathTargets(Motion):
    """Final target positions reached in ``quota`` steps (paper §4.3): ``final`` (k, d) per vertex, or
    ``offset`` (d,) added to the positions the handle had when it started.

    The §4.3 subdivision of the remaining path is done by the handle (it knows the current positions):
    this motion only gives the final targets."""

    final: np.ndarray | None = None
    offset: np.ndarray | None = None
    quota: int = 1
    source: str = ""

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        if self.final is not None:
            return self.final
        return X + np.asarray(self.offset, dtype=float)

    def check_count(self, k: int) -> None:
        if self.final is not None and self.final.shape[0] != k:
            raise ValueError(f"{self.source}: has targets for {self.final.shape[0]} vertices but the selection has {k}")


@dataclass
class FrameTargets(Motion):
    """Per-step per-vertex targets from a file: frames (F, k, d), frame i for step start + i + 1."""

    frames: np.ndarray
    dt: float = field(default=1.0)
    source: str = ""

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        i = round(t / self.dt) - 1
        return self.frames[min(max(i, 0), self.frames.shape[0] - 1)]

    def check_count(self, k: int) -> None:
        if self.frames.shape[1] != k:
            raise ValueError(
                f"{self.source}: has targets for {self.frames.shape[1]} vertices per frame but the selection has {k}"
            )
