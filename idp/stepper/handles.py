"""Handles and kinematic obstacles (paper §4.3, §4.5): per-step Dirichlet targets from scripted motions.

A :class:`Handle` binds a vertex selection to a :class:`~idp.stepper.motions.Motion` over a range of steps.
:class:`HandleSet` is the per-step condition the run loop calls: before each step it gathers the targets of
every active handle and hands them to the step's :class:`~idp.stepper.dirichlet.DirichletTargets`, which the
Newton loop resolves (feasible move, adaptive penalty, hold). A kinematic obstacle is a handle on every
vertex of an obstacle surface: its move is CCD-checked like any other bound move, so it cannot tunnel.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from idp.errors import SceneError
from idp.mesh.selection import Selection
from idp.stepper.dirichlet import DirichletTargets
from idp.stepper.motions import Motion, PathTargets

log = logging.getLogger("idp")


@dataclass
class Handle:
    """A vertex selection of one object driven by a motion from step ``start`` + 1 to ``end``.

    ``object_vertices``: the object's global vertex ids (selections are object-local). ``select_on``:
    ``"rest"`` selects once on the placed input shape, ``"current"`` on the shape at the step the handle
    starts. Past ``end`` the handle holds its last targets until ``release`` (inclusive; None = to the end of
    the run), then lets its vertices go. Targets at step k are ``motion(X, (k − start)·dt)``, X the positions
    at the start; a :class:`~idp.stepper.motions.PathTargets` motion is reached over its quota by subdividing
    the remaining path (§4.3)."""

    name: str
    object_vertices: np.ndarray
    selection: Selection
    motion: Motion
    start: int = 0
    end: int | None = None
    release: int | None = None
    select_on: str = "rest"
    # targets of each step from where the handle's vertices are at its start (one dt of the motion), not from
    # where the handle started: a blocked handle is not pushed further (the authors' per-step scaleVel)
    incremental: bool = False
    vertices: np.ndarray | None = None  # global ids, set when selected
    X: np.ndarray | None = None  # positions when it started acting
    held: np.ndarray | None = None  # incremental handles past `end`: the positions they hold

    def select(self, positions: np.ndarray) -> np.ndarray:
        """Select on ``positions`` (the whole scene's (n, d)); raises SceneError when nothing is selected."""
        try:
            local = self.selection.select(positions[self.object_vertices])
        except IndexError as exc:
            raise SceneError(f"handle {self.name!r}: {exc}") from exc
        if local.size == 0:
            raise SceneError(f"handle {self.name!r}: the selection matches no vertex")
        self.vertices = self.object_vertices[local]
        return self.vertices

    def active(self, step: int) -> bool:
        return self.start < step and (self.release is None or step <= self.release)

    def targets(self, step: int, x: np.ndarray, dt: float) -> np.ndarray:
        """Targets of step ``step`` (1-based) given the current positions ``x`` (the start of that step)."""
        if self.X is None or self.vertices is None:
            if self.vertices is None or self.select_on == "current":
                selected = self.select(x)
                try:
                    self.motion.check_count(selected.size)
                except ValueError as exc:
                    raise SceneError(f"handle {self.name!r}: {exc}") from exc
            self.X = x[self.vertices].copy()
        k = step if self.end is None else min(step, self.end)
        m = self.motion
        if self.incremental:
            cur = x[self.vertices]
            if k < step:  # past the end of the motion: hold where it left the vertices
                if self.held is None:
                    self.held = cur.copy()
                return self.held
            return m.targets(cur, dt)
        if isinstance(m, PathTargets):
            left = self.start + m.quota - k + 1
            cur = x[self.vertices]
            final = m.targets(self.X, 0.0)
            return final if left <= 1 else cur + (final - cur) / left
        return m.targets(self.X, (k - self.start) * dt)

    def state(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        if self.vertices is not None:
            out["vertices"] = self.vertices
        if self.X is not None:
            out["X"] = self.X
        if self.held is not None:
            out["held"] = self.held
        return out

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        if "vertices" in st:
            self.vertices = np.asarray(st["vertices"], dtype=np.int64)
        if "X" in st:
            self.X = np.asarray(st["X"], dtype=float)
        if "held" in st:
            self.held = np.asarray(st["held"], dtype=float)


@dataclass
class HandleSet:
    """The per-step condition that turns every active handle's targets into the step's Dirichlet targets."""

    handles: list[Handle]
    constraint: DirichletTargets
    dt: float
    pinned: np.ndarray | None = None  # (n,) vertices pinned by `fixed`: a handle may not select them
    #: targets streamed from user code: ``stream(step, x) -> (global vertex ids, (k, d) targets)`` or None
    stream: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray] | None] | None = None

    def before_step(self, system, step: int, x: np.ndarray) -> None:
        verts: list[np.ndarray] = []
        targets: list[np.ndarray] = []
        owner: list[str] = []
        for h in self.handles:
            if not h.active(step):
                continue
            t = h.targets(step, x, self.dt)
            assert h.vertices is not None  # targets() selects them
            if self.pinned is not None and np.any(self.pinned[h.vertices]):
                raise SceneError(f"handle {h.name!r} selects vertices that `fixed` pins (step {step})")
            verts.append(h.vertices)
            targets.append(t)
            owner.append(h.name)
        if self.stream is not None:
            got = self.stream(step, x)
            if got is not None:
                sv = np.asarray(got[0], dtype=np.int64).ravel()
                st = np.asarray(got[1], dtype=float)
                if st.shape != (sv.size, x.shape[1]):
                    raise SceneError(
                        f"streamed targets at step {step}: {sv.size} vertex ids but targets of shape {st.shape}"
                    )
                if sv.size and (sv.min() < 0 or sv.max() >= x.shape[0]):
                    raise SceneError(f"streamed targets at step {step}: vertex id out of range [0, {x.shape[0]})")
                verts.append(sv)
                targets.append(st)
                owner.append("streamed")
        if not verts:
            self.constraint.set_targets(np.zeros(0, np.int64), np.zeros((0, x.shape[1])))
            return
        v = np.concatenate(verts)
        uniq, _first, counts = np.unique(v, return_index=True, return_counts=True)
        if np.any(counts > 1):
            shared = int(uniq[np.flatnonzero(counts > 1)[0]])
            names = [name for name, vs in zip(owner, verts, strict=True) if np.any(vs == shared)]
            raise SceneError(
                f"handles {names[0]!r} and {names[1]!r} both act on vertex {shared} at step {step}: overlapping "
                "handles would pull it to two targets (end one of them earlier or make the selections disjoint)"
            )
        groups = [(name, int(vs.size)) for name, vs in zip(owner, verts, strict=True)]
        self.constraint.set_targets(v, np.concatenate(targets), groups)

    def after_step(self, system, step: int, x: np.ndarray) -> None:
        self.constraint.relax()

    def state(self) -> dict[str, np.ndarray]:
        out = {}
        for i, h in enumerate(self.handles):
            for k, v in h.state().items():
                out[f"handle{i}_{k}"] = v
        out["kappa_B"] = np.array(self.constraint.kappa)
        out.update({f"dirichlet_{k}": v for k, v in self.constraint.state().items()})
        return out

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        for i, h in enumerate(self.handles):
            h.load_state({k.split("_", 1)[1]: v for k, v in st.items() if k.startswith(f"handle{i}_")})
        if "kappa_B" in st:
            self.constraint.kappa = float(st["kappa_B"])
        self.constraint.load_state({k.split("_", 1)[1]: v for k, v in st.items() if k.startswith("dirichlet_")})


def check_static_overlaps(handles: list[Handle], num_steps: int) -> None:
    """Build-time check of handles selected on the rest shape: no vertex in two handles active together."""
    fixed = [h for h in handles if h.select_on == "rest" and h.vertices is not None]
    for i, a in enumerate(fixed):
        for b in fixed[i + 1 :]:
            a_end = num_steps if a.release is None else a.release
            b_end = num_steps if b.release is None else b.release
            if max(a.start, b.start) >= min(a_end, b_end):
                continue
            assert a.vertices is not None and b.vertices is not None  # only handles with vertices were kept
            shared = np.intersect1d(a.vertices, b.vertices)
            if shared.size:
                raise SceneError(
                    f"handles {a.name!r} and {b.name!r} overlap ({shared.size} shared vertices, e.g. "
                    f"{int(shared[0])}) while both act (steps {max(a.start, b.start) + 1}..{min(a_end, b_end)}): "
                    "a vertex cannot follow two motions"
                )
