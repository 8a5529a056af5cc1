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
    center: np.ndarray | float | None  # 0.0: the origin; None: the centre of X's bounding box
    law: str = "linear"

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        c = 0.5 * (X.min(axis=0) + X.max(axis=0)) if self.center is None else np.asarray(self.center, dtype=float)
        r = np.asarray(self.rate, dtype=float)
        f = np.exp(r * t) if self.law == "exponential" else 1.0 + r * t
        if np.any(f <= 0):
            raise ValueError(f"scale motion reached a non-positive factor {f} at t = {t:g}")
        return (X - c) * f + c


def _spiral_arc(phi: np.ndarray, pitch: float) -> np.ndarray:
    """Arc length of the Archimedean spiral r = pitch·φ from φ = 0: (pitch/2)(φ√(φ²+1) + asinh φ)."""
    return 0.5 * pitch * (phi * np.sqrt(phi * phi + 1.0) + np.arcsinh(phi))


@dataclass
class Roll(Motion):
    """Rolls a strip up like a carpet (3D; the authors' rose, Fig. 11): a length ``speed``·t of it, from its start
    edge on, is wound onto the Archimedean spiral r = ``pitch``·φ (innermost turn at φ = 2π, radius 2π·pitch)
    about an axis parallel to ``axis``; the rest of the strip stays where it was, tangent to the roll.

    Strip coordinates of a start position X, measured from ``center`` (a point of the start edge on the strip's
    mid-surface): s along ``direction`` (the strip's length), n along ``axis`` × ``direction`` (its thickness;
    the roll rises on that side, so flip ``axis`` to roll the other way) and a along ``axis``. A point with
    s ≤ speed·t goes to the spiral point of arc length s from the innermost turn, moved n inwards; a points keep
    a. Layers lie 2π·pitch apart: keep that above the strip's thickness."""

    axis: np.ndarray
    direction: np.ndarray
    center: np.ndarray
    speed: float
    pitch: float

    def __post_init__(self) -> None:
        a = np.asarray(self.axis, dtype=float)
        u = np.asarray(self.direction, dtype=float)
        if np.linalg.norm(a) == 0 or np.linalg.norm(u) == 0:
            raise ValueError("roll: axis and direction must be non-zero")
        a = a / np.linalg.norm(a)
        u = u - (u @ a) * a
        if np.linalg.norm(u) < 1e-9:
            raise ValueError("roll: direction must not be parallel to axis")
        if not (self.speed > 0 and self.pitch > 0):
            raise ValueError("roll: speed and pitch must be positive")
        self._a, self._u = a, u / np.linalg.norm(u)
        self._w = np.cross(self._a, self._u)  # the strip's normal: the roll rises on this side

    def targets(self, X: np.ndarray, t: float) -> np.ndarray:
        if X.shape[1] != 3:
            raise ValueError("roll: a 3D motion")
        c = np.asarray(self.center, dtype=float)
        rel = X - c
        s, n, a = rel @ self._u, rel @ self._w, rel @ self._a
        length = self.speed * max(t, 0.0)
        wound = (s <= length) & (length > 0)
        out = np.array(X, dtype=float, copy=True)  # the flat part stays put, exactly
        if np.any(wound):
            p = self.pitch
            phi0 = 2.0 * math.pi
            s0 = float(_spiral_arc(np.array(phi0), p))
            # φ of arc length s0 + σ (σ ∈ [0, length]) by Newton on the closed form, started from r ≈ √(2 p σ)
            sig = np.concatenate([s[wound], [length]])
            phi = np.sqrt(phi0 * phi0 + 2.0 * sig / p)
            for _ in range(50):
                f = _spiral_arc(phi, p) - s0 - sig
                phi = phi - f / (p * np.sqrt(phi * phi + 1.0))
                if np.max(np.abs(f)) <= 1e-13 * max(1.0, length):
                    break
            q = p * phi[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1)  # counter-clockwise outwards
            dq = p * np.stack([np.cos(phi) - phi * np.sin(phi), np.sin(phi) + phi * np.cos(phi)], axis=1)
            tang = dq / np.linalg.norm(dq, axis=1, keepdims=True)
            inward = np.stack([-tang[:, 1], tang[:, 0]], axis=1)  # left of the tangent: towards the centre
            # the rigid map taking the outer end (the last entry) to the junction (length, 0) with tangent +u
            te = tang[-1]
            R = np.array([[te[0], te[1]], [-te[1], te[0]]])
            pts = (q[:-1] + n[wound][:, None] * inward[:-1] - q[-1]) @ R.T + np.array([length, 0.0])
            out[wound] = c + pts[:, :1] * self._u + pts[:, 1:] * self._w + a[wound][:, None] * self._a
        return out


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
