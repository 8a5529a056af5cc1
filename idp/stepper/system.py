"""The assembled deformation problem: positions, masses, pinned DOFs, energies and contact."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from idp.contact.model import ContactModel
from idp.energies.elastic import ElasticEnergy
from idp.energies.inertia import Inertia
from idp.energies.term import ElementTerm
from idp.output.parts import Part
from idp.solver.assembly import FixedPatternAssembler, FreeDofMap
from idp.solver.constraint import StepConstraint
from idp.solver.contact_pattern import GrowingBlockPattern
from idp.stepper.rest_shape import RestShapeSchedule

__all__ = ["Body", "RestShapeSchedule", "System", "WeightedTerm"]


@dataclass
class Body:
    """A deformable object: its global vertex range, its elastic energy and its rest-shape schedule."""

    name: str
    vertex_ids: np.ndarray
    elastic: ElasticEnergy
    schedule: RestShapeSchedule


@dataclass
class WeightedTerm:
    """An element energy term of E with its weight: the step energy holds h · weight · term(x)."""

    name: str
    term: ElementTerm
    weight: float = 1.0


@dataclass
class System:
    """Everything one artificial time step needs (paper eq. 6).

    E(x) = Σ body elastic energies + Σ ``extra_terms`` (membrane, bending, smoothing, ...); the Newton loop
    sees all of them as :attr:`terms`. ``step_constraint`` (e.g. §4.3 Dirichlet targets,
    :class:`idp.stepper.dirichlet.DirichletTargets`) adds its penalty and holds DOFs during a step;
    ``conditions`` are called by the run loop before and after each step (handles, scripts, plasticity)."""

    dim: int
    x: np.ndarray  # (n, d) current positions, deformables first then obstacles
    masses: np.ndarray  # (n,) lumped masses (0 on obstacle vertices)
    free_mask: np.ndarray  # (n*d,) True where the DOF is optimised
    bodies: list[Body]
    parts: list[Part]
    h: float
    contact: ContactModel | None = None
    num_dynamic_vertices: int = 0
    meta: dict = field(default_factory=dict)
    extra_terms: list[WeightedTerm] = field(default_factory=list)
    step_constraint: StepConstraint | None = None
    conditions: list = field(default_factory=list)
    linear_terms: list = field(default_factory=list)  # value(x)/gradient(x) only, e.g. −β xᵀN (no Hessian)
    # terms over vertex pairs that change between steps (sticky links, :class:`idp.energies.pair_springs.PairSprings`):
    # value, gradient and Hessian blocks that join the contact blocks
    pair_terms: list = field(default_factory=list)
    # set by a condition for the step about to be solved: the inertia target x̃ of ½‖x − x̃‖²_M when it is not
    # the previous state (animation repair: the input frame), and whether every elastic term is at rest there
    inertia_target: np.ndarray | None = None
    target_at_rest: bool = False

    def __post_init__(self) -> None:
        self.dof_map = FreeDofMap(self.free_mask)
        self.inertia = Inertia(self.masses, self.dim)
        self.terms: list[WeightedTerm] = [WeightedTerm(b.name, b.elastic) for b in self.bodies] + list(self.extra_terms)
        self.assembler = FixedPatternAssembler(
            [t.term.element_dofs() for t in self.terms], self.dof_map, dim=self.dim, positions=self.x
        )
        self.contact_pattern = None
        if self.contact is not None:
            self.collision_dofs = self.contact.collision_dofs()
            self.collision_dof_to_free = self.dof_map.global_to_free[self.collision_dofs]
            kept = self.collision_dof_to_free[self.collision_dof_to_free >= 0]
            if self.assembler.layout is not None and np.all(np.diff(kept) > 0):
                self.contact_pattern = GrowingBlockPattern(self.assembler.layout)
                # collision-mesh vertex → free vertex (whole vertices are free or pinned here), −1 if not free
                first = self.collision_dof_to_free.reshape(-1, self.dim)[:, 0]
                self.collision_vertex_to_free = np.where(first >= 0, first // self.dim, -1).astype(np.int64)
        first_dof = self.dof_map.global_to_free.reshape(-1, self.dim)[:, 0]
        self.vertex_to_free = np.where(first_dof >= 0, first_dof // self.dim, -1).astype(np.int64)
        dyn = self.masses[: self.num_dynamic_vertices]
        self.average_mass = float(dyn[dyn > 0].mean()) if np.any(dyn > 0) else 1.0

    def set_masses(self, masses: np.ndarray) -> None:
        """Replace the lumped masses M (a normal flow rebuilds them from the current shape)."""
        self.masses = np.asarray(masses, dtype=float)
        self.inertia = Inertia(self.masses, self.dim)
        if self.step_constraint is not None and hasattr(self.step_constraint, "masses"):
            self.step_constraint.masses = self.masses
        for t in self.linear_terms:  # terms whose force scales with the masses (gravity)
            if hasattr(t, "set_masses"):
                t.set_masses(self.masses)

    @property
    def elements(self) -> list[np.ndarray]:
        return [b.elastic.elements for b in self.bodies]

    def set_rest_shape_for_step(self, step: int) -> None:
        """Apply every body's rest-shape schedule for the step about to be solved (1-based)."""
        for b in self.bodies:
            b.schedule.apply(b.elastic, step)

    def elastic_value(self, x: np.ndarray) -> float:
        """E(x) without contact: Σ weight · term(x) over every element term, plus the linear terms."""
        v = sum(t.weight * t.term.value(x) for t in self.terms)
        return float(v + sum(t.value(x) for t in self.linear_terms) + sum(t.value(x) for t in self.pair_terms))

    def elastic_gradient(self, x: np.ndarray) -> np.ndarray:
        g = np.zeros(x.size)
        for t in self.terms:
            g += t.weight * t.term.gradient(x)
        for t in self.linear_terms:
            g += t.gradient(x)
        for t in self.pair_terms:
            g += t.gradient(x)
        return g

    def deformable_volume(self, x: np.ndarray) -> float:
        from idp.mesh.quality import signed_volumes

        return float(sum(signed_volumes(x, b.elastic.elements).sum() for b in self.bodies))
