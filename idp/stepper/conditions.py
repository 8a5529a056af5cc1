"""Per-step conditions on a body's material and rest state (paper §4.5, §7.1, §7.5).

Each is a small object the run loop calls at fixed points (``before_step`` / ``after_step``), with its own
checkpoint ``state`` so that a resumed run continues exactly: material stages (stiffness per step range),
plasticity (von Mises return mapping at the start of each step, X̄⁻¹ ← X⁻¹ Z(F)) and bake (the current shape
becomes the rest shape at the end of a chosen step).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from idp.energies.plasticity import VonMisesPlasticity

if TYPE_CHECKING:  # annotations only
    from idp.stepper.system import Body


def _rest_state(elastic) -> dict[str, np.ndarray]:
    """The base rest frames and volume weights of an elastic energy (changed by plasticity and bake)."""
    return {"base": np.array(elastic.base_rest_frames), "volumes": np.array(elastic.volumes)}


def _load_rest_state(elastic, st: dict[str, np.ndarray]) -> None:
    if "base" in st:
        elastic.set_base_rest_frames(st["base"], st["volumes"])


@dataclass
class MaterialStages:
    """Young's modulus / Poisson ratio of one body per step range: stage i applies from step ``starts[i]`` + 1."""

    body: Body
    starts: list[int]
    materials: list[tuple[float, float]]
    initial: tuple[float, float]
    _current: int = -1

    def before_step(self, system, step: int, x: np.ndarray) -> None:
        idx = -1
        for i, s in enumerate(self.starts):
            if step > s:
                idx = i
        if idx != self._current:
            E, nu = self.initial if idx < 0 else self.materials[idx]
            self.body.elastic.set_material(E, nu)
            self._current = idx


@dataclass
class Plasticity:
    """Von Mises plasticity of one body, return-mapped at the start of every step (paper §4.5)."""

    body: Body
    model: VonMisesPlasticity
    part_index: int
    yielded: list[int] = field(default_factory=list)

    def before_step(self, system, step: int, x: np.ndarray) -> None:
        self.yielded.append(self.model.apply(self.body.elastic, x))

    def cell_data(self) -> dict[str, dict[int, np.ndarray]]:
        m = self.body.elastic.elements.shape[0]
        alpha = self.model.plastic_strain if self.model.plastic_strain is not None else np.zeros(m)
        return {"plastic_strain": {self.part_index: alpha}}

    def state(self) -> dict[str, np.ndarray]:
        st = _rest_state(self.body.elastic)
        if self.model.plastic_strain is not None:
            st["alpha"] = np.array(self.model.plastic_strain)
        return st

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        _load_rest_state(self.body.elastic, st)
        if "alpha" in st:
            self.model.plastic_strain = np.array(st["alpha"], dtype=float)


@dataclass
class Bake:
    """At the end of step ``step`` the body's current shape becomes its rest shape (paper §4.5 "bake")."""

    body: Body
    step: int
    done: bool = False

    def before_step(self, system, step: int, x: np.ndarray) -> None:
        return None

    def after_step(self, system, step: int, x: np.ndarray) -> None:
        if step == self.step:
            self.body.elastic.bake(x)
            self.body.schedule.rebased_at = step
            self.done = True

    def state(self) -> dict[str, np.ndarray]:
        return {**_rest_state(self.body.elastic), "done": np.array(self.done)} if self.done else {}

    def load_state(self, st: dict[str, np.ndarray]) -> None:
        if st.get("done") is not None and bool(st["done"]):
            _load_rest_state(self.body.elastic, st)
            self.body.schedule.rebased_at = self.step
            self.done = True
