"""Rest-shape scripting per body (paper §4.5 "Shape"): growth, anisotropic and per-region scale, bake.

The effective rest frame of element t at step k is T_t(k) · X̄_t, with X̄_t the body's base rest frames (the
input shape, or the last baked shape, or the plastic rest frames) and T_t(k) = diag of the product of the
growth factor and every active scale script's factor (per region). Scripts are pure functions of the step,
so a resumed run recomputes them; a bake re-bases them (factors after a bake are relative to the bake step).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ScaleScript:
    """Rest-shape scale 1 + rate·(min(k, end) − start) for k > start (per axis), on ``elements`` (None: all)."""

    start: int
    end: int
    rate: np.ndarray
    elements: np.ndarray | None = None  # (m,) bool region

    def factor(self, step: int) -> np.ndarray:
        k = min(max(step, self.start), self.end)
        return 1.0 + np.asarray(self.rate, dtype=float) * (k - self.start)


@dataclass
class RestShapeSchedule:
    """Growth (scale(k) = base · (1 + rate · min(k, steps))) and scale scripts of one body."""

    base: np.ndarray
    growth_rate: float = 0.0
    growth_steps: int = 0
    scripts: list[ScaleScript] = field(default_factory=list)
    rebased_at: int | None = None  # step of the last bake: factors are relative to their value there

    def _growth(self, step: int) -> np.ndarray:
        k = min(max(step, 0), self.growth_steps)
        return self.base * (1.0 + self.growth_rate * k)

    def factor(self, step: int) -> np.ndarray:
        """Uniform part (d,) of the rest scale at ``step`` (growth only)."""
        f = self._growth(step)
        if self.rebased_at is not None:
            f = f / self._growth(self.rebased_at)
        return f

    def element_factors(self, step: int, num_elements: int) -> np.ndarray | None:
        """(m, d) per-element scale when scale scripts apply, else None (the uniform :meth:`factor` is enough)."""
        if not self.scripts:
            return None
        out = np.tile(self.factor(step), (num_elements, 1))
        for s in self.scripts:
            f = s.factor(step)
            if self.rebased_at is not None:
                f = f / s.factor(self.rebased_at)
            if s.elements is None:
                out *= f
            else:
                out[s.elements] *= f
        return out

    def apply(self, elastic, step: int) -> None:
        """Set ``elastic``'s rest frames for ``step``."""
        per_element = self.element_factors(step, elastic.elements.shape[0])
        if per_element is None:
            elastic.set_rest_scale(self.factor(step))
            return
        d = per_element.shape[1]
        T = np.zeros((per_element.shape[0], d, d))
        T[:, np.arange(d), np.arange(d)] = per_element
        elastic.set_rest_transform(T)
