"""Animation repair's per-step condition (paper §7.3, eq. 8): step s repairs input frame f^s.

Before step s it makes f^s the rest shape of every membrane and bending term and the step's inertia target
(``system.inertia_target``), and states that the elastic terms are at rest there, so the solver returns f^s
itself, bit for bit, when the straight move from x^{s−1} to f^s is collision-free and nothing is within d̂ of
anything there (:meth:`idp.solver.newton.StepSolver.solve`). The prescribed vertices (the mannequin's head)
get f^s as §4.3 Dirichlet targets through :meth:`targets` (the handle set's stream), so they follow the input
exactly unless that would collide. After the step it reports the deviation from the input and the crossing
pairs of input and output.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idp.contact.intersections import intersecting_pair_keys, pairs_within
from idp.errors import MeshError


class RepairFrames:
    """Step s ≥ 1 repairs ``frames[s]`` of ``sequence``; ``frames[0]`` is the start state x¹ = f¹."""

    report_key = "repair"

    def __init__(
        self,
        sequence: Any,
        frames: list[int],
        vertex_ids: np.ndarray,
        faces: np.ndarray,
        terms: list,
        prescribed: np.ndarray,
        preserved: set,
    ) -> None:
        """``vertex_ids``: the global ids of the sequence's vertices (row i of a frame is ``vertex_ids[i]``);
        ``faces``: its triangles in global ids; ``terms``: the membrane/bending terms whose rest shape follows the
        input; ``prescribed``: (k,) sequence vertex ids that follow the input; ``preserved``: the first frame's
        crossing pairs kept as features (global vertex-id keys)."""
        self.sequence = sequence
        self.frames = list(frames)
        self.vertex_ids = np.asarray(vertex_ids, dtype=np.int64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.terms = list(terms)
        self.prescribed = np.asarray(prescribed, dtype=np.int64)
        self.preserved = preserved
        self.input: np.ndarray | None = None  # f^s of the step being solved, in the sequence's own numbering
        self.step = 0  # the step being solved, or the last one finished

    def frame_index(self, step: int) -> int:
        """The input frame a step produces (step 0: the first frame)."""
        return self.frames[step]

    def _read(self, step: int) -> np.ndarray:
        return self.sequence.frame(self.frames[step])

    def before_step(self, system: Any, step: int, x: np.ndarray) -> None:
        f = self._read(step)
        target = x.copy()
        target[self.vertex_ids] = f
        for term in self.terms:
            try:
                term.set_rest_shape(target)
            except ValueError as exc:  # a degenerate triangle in the input frame
                raise MeshError(f"{self.sequence.describe(self.frames[step])}: {exc}") from None
        system.inertia_target = target
        system.target_at_rest = True
        self.input, self.step = f, step

    def targets(self, step: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The prescribed vertices' Dirichlet targets for ``step`` (the handle set's stream)."""
        if self.prescribed.size == 0 or self.input is None:
            return None
        return self.vertex_ids[self.prescribed], self.input[self.prescribed]

    def after_step(self, system: Any, step: int, x: np.ndarray) -> None:
        system.inertia_target = None
        system.target_at_rest = False

    def state(self) -> dict[str, np.ndarray]:
        return {"step": np.array(self.step)}

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        if "step" in st:
            self.step = int(st["step"])

    def output(self, x: np.ndarray) -> np.ndarray:
        """The repaired frame in the sequence's numbering."""
        return x[self.vertex_ids]

    def unchanged(self, x: np.ndarray) -> bool:
        return self.input is not None and bool(np.array_equal(self.output(x), self.input))

    def _crossings(self, v: np.ndarray) -> tuple[int, int, int]:
        """(crossing pairs, those not among the preserved first-frame pairs, those of them whose every vertex is
        prescribed) of a frame in global ids."""
        X = np.zeros((int(self.vertex_ids.max()) + 1, 3))
        X[self.vertex_ids] = v
        keys = intersecting_pair_keys(X, self.faces)
        new = keys - self.preserved
        group = np.zeros(X.shape[0], dtype=bool)
        group[self.vertex_ids[self.prescribed]] = True
        return len(keys), len(new), pairs_within(new, group)

    def report(self, system: Any, x: np.ndarray) -> dict:
        """Deviation from the input frame (per vertex: max, mean; max per coordinate as the manifest measures the
        authors' output), relative to the first frame's bounding-box diagonal, and crossing pairs of input and
        output; of the crossings not preserved, those whose every vertex is prescribed (the input's own crossings
        of the prescribed parts, which they follow when their pairs are left out of contact).
        """
        if self.input is None:  # the start state (of a run, or of a resumed run)
            self.input = self._read(self.step)
        step_frame = self.input
        out = self.output(x)
        d = out - step_frame
        dist = np.linalg.norm(d, axis=1)
        diag = system.meta.get("bbox_diagonal")
        in_pairs, in_new, in_prescribed = self._crossings(step_frame)
        out_pairs, out_new, out_prescribed = (
            (in_pairs, in_new, in_prescribed) if not np.any(d) else self._crossings(out)
        )
        return {
            "frame": self.frames[self.step],
            "unchanged": bool(np.array_equal(out, step_frame)),
            "max_deviation": float(dist.max(initial=0.0)),
            "mean_deviation": float(dist.mean()) if dist.size else 0.0,
            "max_coordinate_deviation": float(np.abs(d).max(initial=0.0)),
            "max_deviation_relative": float(dist.max(initial=0.0)) / diag if diag else None,
            "changed_vertices": int(np.count_nonzero(dist > 0)),
            "input_crossing_pairs": in_pairs,
            "input_crossing_pairs_not_preserved": in_new,
            "output_crossing_pairs": out_pairs,
            "output_crossing_pairs_not_preserved": out_new,
            "input_crossing_pairs_prescribed": in_prescribed,
            "output_crossing_pairs_prescribed": out_prescribed,
        }
