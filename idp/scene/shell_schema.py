"""Scene sections of shells (triangle surfaces in 3D, paper §4.4) and of normal flow (paper §7.2)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, Strict, model_validator

from idp.scene.schema_base import Bool, PosFloat, _Model, rule_error

NonNegFloat = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)]
#: the bending's Newton Hessian (:data:`idp.energies.bending.BENDING_HESSIANS`)
BendingHessian = Literal["projected", "gauss_newton"]


class ShellMaterial(_Model):
    """Material of a shell object: StVK membrane (``youngs_modulus`` E, ``poisson_ratio`` ν, ``thickness`` t) and
    discrete-shell bending scaled by ``bending`` (stiffness ``bending`` · E t³ / (12 (1 − ν²))), whose Newton
    Hessian is ``bending_hessian``: the exact one PSD-projected per hinge, or its Gauss–Newton part
    (:mod:`idp.energies.bending`).

    E = 0 turns the membrane off and ``bending`` = 0 the bending off (the normal flow's shells carry no elastic
    energy, as in the authors' set-up; a shell without a ``shell`` table in a scene with ``[flow]`` gets exactly
    that: E = 0, bending 0, density 1, thickness 1). Lumped masses are ``density`` · ``thickness`` · (vertex area)."""

    youngs_modulus: NonNegFloat = 1e4
    poisson_ratio: Annotated[float, Strict(), Field(gt=-1, lt=0.5, allow_inf_nan=False)] = 0.3
    thickness: PosFloat = 1e-3
    density: PosFloat = 1000.0
    bending: NonNegFloat = 1.0
    bending_hessian: BendingHessian = "projected"


#: a flow scene's default Newton tolerance: RMS step per vertex below this fraction of |β| (solver.newton_norm =
#: "rms").  Cat, 10 steps: 0.02 → 271 iterations, volume x2.718; 0.05 → 66, x2.706; 0.1 (the reference's own
#: threshold, h = 0.5) → 59, x2.656.
FLOW_TOL_FRACTION = 0.05


class FlowConfig(_Model):
    """Normal flow (paper §7.2, eq. 7): E(x, Nᵗ) = B(x) − γ ½ xᵀLx − β xᵀNᵗ over every shell object.

    ``beta`` β: flow speed, > 0 outward, < 0 inward (with ``time.h`` = 1 and lumped-unit normals a free vertex
    moves about β per step). ``gamma`` γ ≥ 0: smoothing intensity. ``laplacian``: ``area`` (umbrella weights
    Σ A_t/6 from the initial triangle areas, as the authors' code) or ``cotangent``. ``normals``: ``mass``
    (Nᵢ = mᵢ n̂ᵢ with the masses of M, as the authors' force: an unobstructed, unsmoothed vertex moves exactly
    β n̂ᵢ per step), ``lumped_unit`` (Nᵢ = aᵢ n̂ᵢ with aᵢ the *current* lumped area while M keeps the start
    areas, so the push of a vertex grows with its triangles; on the cat a vertex whose area grew 10⁴-fold flew
    off) or ``area`` (Σ A_t n̂_t / 3). ``recompute``: when M and L are rebuilt from
    the current shape — ``auto`` every step for negative flows (the paper does, for smoother sequences) and
    never for positive ones, or ``always`` / ``never``. ``fix_boundary``: pin every boundary vertex of open
    shells (default, as for the fonts).

    The authors' parameters map exactly as: magnitude → ``beta`` = magnitude (their dt = s and force
    magnitude·mᵢ·n̂ᵢ/s² make the per-step push equal to the magnitude) and smoothIntensity s → ``gamma`` = s
    (their step adds s·(−½xᵀLx) with L the A_t/6-weighted umbrella Laplacian of ``laplacian = "area"``), with
    ``time.h`` = 1.  Checked against the authors' code run on the same meshes (docs/normal-flow.md)."""

    beta: Annotated[float, Strict(), Field(allow_inf_nan=False)]
    gamma: NonNegFloat = 0.5
    laplacian: Literal["area", "cotangent"] = "area"
    normals: Literal["mass", "lumped_unit", "area"] = "mass"
    recompute: Literal["auto", "always", "never"] = "auto"
    fix_boundary: Bool = True

    @model_validator(mode="after")
    def _nonzero(self) -> FlowConfig:
        if self.beta == 0:
            raise rule_error([("beta", "must be non-zero (> 0 flows outward, < 0 inward)")])
        return self

    @property
    def recompute_every_step(self) -> bool:
        """Whether M and L follow the current shape (``auto``: for negative flows)."""
        return self.recompute == "always" or (self.recompute == "auto" and self.beta < 0)
