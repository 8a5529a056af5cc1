"""Scene section of animation repair (paper §7.3): which sequence, which frames, what follows the input."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from idp.scene.schema_base import Bool, Float, NonNegInt, _Model, rule_error
from idp.scene.shell_schema import BendingHessian

#: the authors' repair set-up (manifest, repair/): d̂ = 1e-2 absolute, dt = 0.04 (h = dt²)
REPAIR_DHAT = 1e-2
#: the authors' shell stopping rule: RMS Newton step per vertex / dt ≤ 1e-3 (reference notes, "Newton loop")
REPAIR_NEWTON_TOL = 1e-3
#: the bending's Newton Hessian in a repair unless the shell sets it: 2c∇θ∇θᵀ (Kick: 837 instead of 967 Newton
#: iterations, 301–346 instead of 385 s of stepping the same session, the same deviations; docs/animation-repair.md)
REPAIR_BENDING_HESSIAN: BendingHessian = "gauss_newton"


class RepairConfig(_Model):
    """Animation repair (paper §7.3, eq. 8): frame s is one step x^s = argmin ½‖x − f^s‖²_M + h·E(x, f^s) from
    x^{s−1}, E = StVK membrane + discrete-shell bending with f^s as rest shape, plus the barrier.

    ``input``: the sequence (a folder or glob of OBJ frames, a ``.pvd`` VTU series, an ``.npz`` with
    ``vertices`` (F, n, 3) and ``faces``, or a USD file with time-sampled points; ``usd_prim`` picks the mesh).
    ``start``/``stop``: the frames repaired (Python slice, ``stop`` exclusive; default all); frame ``start`` is
    x¹. ``prescribed``: vertex selections (boxes, relative to the first frame's bounding box when ``relative``,
    or index lists) that follow the input exactly, through §4.3 Dirichlet targets (the mannequin's head and
    neck). ``first_frame``: a first frame whose surfaces already cross is an ``error`` (default; the pairs are
    named) or its crossings are ``preserve``d as features through the whole sequence (paper §5.5; the authors'
    mannequin has ~500 such pairs, its nails and ears, in every frame): every other pair stays guarded and
    every output frame is certified against them. ``output``: the repaired sequence's form, ``same`` as the
    input (default) or ``obj`` / ``pvd`` / ``npz`` / ``usd``. ``prescribed_contact``: pairs among prescribed vertices
    only are left out of the barrier and CCD (``follow_input``, default, as the authors' code does with its
    Dirichlet vertices: the prescribed parts follow the input exactly, also where the input's own prescribed parts
    pass through each other — such crossings are reported per frame, never any other), or ``guarded`` like every
    other pair (the prescribed parts never cross, and lag the input where it crosses itself).

    The scene's single shell object is the sequence itself: leave ``objects`` out (one is made, with the
    authors' material E = 100, ν = 0.4, thickness 0.01, bending 1, density 1000), or give exactly one shell
    object whose ``mesh`` is ``input`` to set the material."""

    input: Path
    usd_prim: str | None = None
    start: NonNegInt = 0
    stop: NonNegInt | None = None
    prescribed: list[RepairSelector] = Field(default_factory=list)
    first_frame: Literal["error", "preserve"] = "error"
    output: Literal["same", "obj", "pvd", "npz", "usd"] = "same"
    prescribed_contact: Literal["follow_input", "guarded"] = "follow_input"

    @model_validator(mode="after")
    def _range(self) -> RepairConfig:
        if self.stop is not None and self.stop < self.start + 2:
            raise rule_error([("stop", f"must be at least start + 2 = {self.start + 2} (two frames to repair)")])
        return self


class RepairSelector(_Model):
    """Vertices of the first frame that follow the input exactly: an axis-aligned ``box`` [lo, hi] (relative to
    the first frame's bounding box when ``relative``: 0 = min, 1 = max per axis) or an ``indices`` list."""

    box: list[list[Float]] | None = None
    relative: Bool = False
    indices: list[NonNegInt] | None = None

    @model_validator(mode="after")
    def _one(self) -> RepairSelector:
        if (self.box is None) == (self.indices is None):
            raise rule_error([("", "give exactly one of `box` or `indices`")])
        if self.box is not None:
            from idp.scene.schema_base import check_corner_box

            check_corner_box(self.box)
            if any(len(c) != 3 for c in self.box):
                raise rule_error([("box", "corners must have 3 entries")])
        if self.indices is not None and not self.indices:
            raise rule_error([("indices", "must not be empty")])
        return self


RepairConfig.model_rebuild()
