"""Per-step distortion figures of the deformable bodies (paper §7.4): worst, 99th percentile and mean Ψ_SD.

A reporting condition: the run loop records :meth:`DistortionMonitor.report` in every step of ``stats.json``
(under ``"distortion"``) and writes the last per-element values as the ``distortion`` cell field of the VTU
frames, so min-max runs can be compared by the measure the paper quotes (Ψ_SD = ‖F‖² + ‖F⁻¹‖², 4 isometric
in 2D, 6 in 3D) whatever energy drives them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from idp.mesh.distortion import distortion_summary, symmetric_dirichlet_distortion

if TYPE_CHECKING:  # annotations only
    from idp.stepper.system import Body


class DistortionMonitor:
    """Reports Ψ_SD of every body after each step and offers it as a VTU cell field."""

    report_key = "distortion"

    def __init__(self, bodies: list[Body], part_indices: list[int]) -> None:
        self.bodies = bodies
        self.part_indices = part_indices
        self._last: list[np.ndarray] | None = None

    def before_step(self, system: Any, step: int, x: np.ndarray) -> None:
        return None

    def values(self, x: np.ndarray) -> list[np.ndarray]:
        """Per body, Ψ_SD of each element at ``x`` (against the current rest frames)."""
        return [symmetric_dirichlet_distortion(b.elastic.deformation_gradients(x)) for b in self.bodies]

    def report(self, system: Any, x: np.ndarray) -> dict[str, Any]:
        self._last = self.values(x)
        psi = np.concatenate(self._last) if self._last else np.zeros(0)
        vol = np.concatenate([b.elastic.volumes for b in self.bodies]) if self.bodies else np.zeros(0)
        out: dict[str, Any] = distortion_summary(psi, vol)
        if len(self.bodies) > 1:
            out["bodies"] = {
                b.name: distortion_summary(p, b.elastic.volumes) for b, p in zip(self.bodies, self._last, strict=True)
            }
        return out

    def cell_data(self) -> dict[str, dict[int, np.ndarray]]:
        if self._last is None:
            return {}
        return {"distortion": dict(zip(self.part_indices, self._last, strict=True))}
