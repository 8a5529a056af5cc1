"""Scene description: pydantic v2 models that are both the file schema and the Python API.

Every model forbids unknown keys. Rules that need several fields (or the scene's ``dim``)
raise a ``scene_rule`` error whose context lists ``(sub-path, message)`` pairs, so that
:func:`idp.scene.load.format_validation_error` can name the exact key.  Building a model
directly in Python (``Scene(...)``, ``Material(...)``) raises :class:`idp.errors.SceneError`
with the same one-line-per-problem message.
"""

from __future__ import annotations

import collections
import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    Field,
    Strict,
    field_validator,
    model_validator,
)

from idp.scene.conditions_schema import (
    DirichletConfig,
    HandleSpec,
    KeyframeSpec,
    KinematicSpec,
    MaterialStageSpec,
    MotionSpec,
    PlasticitySpec,
    RestScriptSpec,
    RotationSpec,
    SelectionSpec,
    SphereSpec,
)
from idp.scene.layout_schema import (
    GridSpec,
    InstancesSpec,
    InstanceTransform,
    RandomSpec,
    RingSpec,
    TransformSpec,
    expand_instances,
)
from idp.scene.repair_schema import (
    REPAIR_BENDING_HESSIAN,
    REPAIR_DHAT,
    REPAIR_NEWTON_TOL,
    RepairConfig,
    RepairSelector,
)
from idp.scene.schema_base import (
    Bool,
    Float,
    Name,
    NonNegInt,
    PosFloat,
    PosInt,
    PosVec3,
    Res2,
    Res3,
    Rotation,
    Scale,
    Vec2,
    Vec3,
    _auto_or_number,
    _check_box,
    _check_scale,
    _Model,
    check_corner_box,
    rule_error,
)
from idp.scene.shell_schema import FLOW_TOL_FRACTION, FlowConfig, ShellMaterial
from idp.scene.stages_schema import AnchorSpec, RemeshSpec, StageObjectSettings, StageSpec, check_stages
from idp.scene.sticky_schema import StickyConfig, check_sticky

# ---------------------------------------------------------------------------------------------
# Global sections


class TimeConfig(_Model):
    """Artificial time stepping."""

    h: PosFloat = 0.0016
    steps: PosInt = 60
    stop_when_stationary: Bool = False
    stationary_tol: PosFloat = 1e-5
    # stop after the first step whose Newton solve needs at most one iteration (the paper's rule for UV maps, §7.4)
    stop_after_single_iteration: Bool = False


class SolverConfig(_Model):
    """Projected Newton settings."""

    newton_tol: PosFloat = 1e-2
    newton_norm: Literal["max", "rms"] = "max"
    max_newton_iterations: PosInt = 200
    on_nonconvergence: Literal["warn", "error"] = "warn"
    linear_solver: Literal["auto", "cholmod", "scipy"] = "auto"
    check_every_iterate: Bool = False
    inversion_eta: Annotated[float, Strict(), Field(gt=0, lt=1)] = 0.1
    # after a full Newton step, try 2×, 4×, ... up to this multiple while each is feasible and lowers the energy;
    # "auto": 2p for p-norm energies with p > 1 (Newton falls short on a power law), else 1 (off)
    line_search_extrapolation: Literal["auto"] | float = "auto"
    # search matrices that also see contact pairs within this multiple of d̂ once CCD cuts a step short (0: off;
    # docs/benchmarks.md, "Contact look-ahead"); the energy, line search, CCD and stopping rule are unchanged.
    # "auto": 2 with the compiled barrier when no shell deforms, else 0 (idp.solver.newton.contact_lookahead_reach)
    contact_lookahead: Literal["auto"] | float = "auto"
    # bodies that cannot meet along a Newton move each take their own step length (compiled 3D barrier;
    # idp.solver.islands, docs/benchmarks.md "Islands"); false: one step length for the whole move
    island_steps: Bool = False
    # guards (docs/scene-reference.md, "Running on shared machines"): a step's wall-clock limit in seconds, and the
    # memory a step may use ("4G", "512M" with powers of 1024, or a number of bytes) on top of the memory available
    max_step_seconds: PosFloat | None = None
    max_memory: int | str | None = None

    @field_validator("line_search_extrapolation", mode="before")
    @classmethod
    def _extrapolation(cls, v: Any) -> Any:
        return _auto_or_number(v, 1.0, inclusive=True, note=" (1: off)")

    @field_validator("contact_lookahead", mode="before")
    @classmethod
    def _lookahead(cls, v: Any) -> Any:
        v = _auto_or_number(v, 0.0, inclusive=True, note=" (0: off)")
        if isinstance(v, float) and 0.0 < v <= 1.0:
            raise ValueError('contact_lookahead must be "auto", 0 (off) or a multiple of dhat above 1, e.g. 2')
        return v

    @field_validator("max_memory", mode="before")
    @classmethod
    def _max_memory(cls, v: Any) -> Any:
        if v is None:
            return v
        from idp.solver.memory import parse_memory_size

        parse_memory_size(v)  # ValueError naming the accepted forms
        if isinstance(v, str):
            return v.strip()
        if isinstance(v, float):
            return int(v)
        return v

    @property
    def max_memory_bytes(self) -> int | None:
        """``max_memory`` in bytes (None when unset)."""
        from idp.solver.memory import parse_memory_size

        return None if self.max_memory is None else parse_memory_size(self.max_memory)


class ContactConfig(_Model):
    """IPC contact settings."""

    enabled: Bool = True
    dhat: PosFloat = 1e-3
    dhat_mode: Literal["absolute", "relative"] = "absolute"
    kappa: Literal["auto"] | float = "auto"
    adaptive_kappa: Bool = True
    # IPC's gradient-balance start of κ (kappa = "auto"): at every step, never lowering κ (default), or only at
    # the first step with a pair within d̂ (a repair's default: a frame whose prescribed head starts off its targets
    # must not raise κ for every later frame; docs/animation-repair.md)
    kappa_init: Literal["every_step", "once"] = "every_step"
    ccd: Literal["additive", "tight_inclusion"] = "tight_inclusion"
    broad_phase: Literal["lbvh", "hash_grid", "spatial_hash", "sweep_and_prune", "brute_force"] = "lbvh"
    barrier: Literal["compiled", "ipctk"] = "compiled"
    preserve_input_intersections: Bool = False

    @field_validator("kappa", mode="before")
    @classmethod
    def _kappa(cls, v: Any) -> Any:
        return _auto_or_number(v, 0.0, inclusive=False)


class OutputConfig(_Model):
    """What to write and where."""

    dir: Path = Path("out")
    every: PosInt = 1
    obj: Bool = True
    vtu: Bool = True
    png: Bool = True
    # per-step distortion figures (worst / 99th percentile / mean symmetric Dirichlet) in stats.json and a
    # `distortion` cell field in the VTU frames; default: on when a material has power > 1 or an object is a UV map
    distortion: Bool | None = None
    # the scene's up axis in pictures (3D): "auto" = against gravity when the scene has gravity, else z
    up: Literal["auto", "x", "y", "z"] = "auto"


# ---------------------------------------------------------------------------------------------
# Per-object sections


class Material(_Model):
    """Elastic material of a deformable object.

    ``neo_hookean`` and ``symmetric_dirichlet`` are inversion barriers (every iterate inversion-free);
    ``arap`` and ``stvk`` are not: the scene warns, contact stays guarded, and the certificate reports inverted
    elements instead of failing for them."""

    model: Literal["neo_hookean", "symmetric_dirichlet", "arap", "stvk"] = "neo_hookean"
    youngs_modulus: PosFloat = 1e4
    poisson_ratio: Annotated[float, Strict(), Field(gt=-1)] = 0.4
    density: PosFloat = 1000.0
    weight: PosFloat | None = None
    # p of the p-norm extension E_p = r(p) Σ v Ψ̂^p (paper §7.4, eq. 9) of symmetric Dirichlet or neo-Hookean
    power: Annotated[float, Strict(), Field(ge=1, allow_inf_nan=False)] = 1.0

    @field_validator("poisson_ratio")
    @classmethod
    def _nu(cls, v: float) -> float:
        if v >= 0.5:
            raise ValueError(f"must be < 0.5 (got {v}): incompressible materials (nu >= 0.5) are not supported")
        return v

    @property
    def mu(self) -> float:
        """Lamé shear modulus E / (2 (1 + nu))."""
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lam(self) -> float:
        """Lamé first parameter E nu / ((1 + nu)(1 - 2 nu))."""
        nu = self.poisson_ratio
        return self.youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @model_validator(mode="after")
    def _weight(self) -> Material:
        if self.model == "symmetric_dirichlet":
            if self.weight is None:
                self.weight = self.mu / 4.0
        elif self.model == "arap":
            if self.weight is None:
                self.weight = self.mu
        elif self.weight is not None:
            raise rule_error([("weight", 'only used by model = "symmetric_dirichlet" or "arap"')])
        if self.power != 1.0:
            if self.model not in ("symmetric_dirichlet", "neo_hookean"):
                raise rule_error(
                    [("power", 'the p-norm extends model = "symmetric_dirichlet" or "neo_hookean" (barrier energies)')]
                )
            if self.model == "neo_hookean" and self.poisson_ratio < 0:
                raise rule_error([("power", "a neo-Hookean p-norm needs poisson_ratio >= 0")])
        return self


class RestShape(_Model):
    """Rest-shape stretch and growth: factor after step k = scale * (1 + growth_rate * min(k, growth_steps))."""

    scale: Scale = 1.0
    growth_rate: Float = 0.0
    growth_steps: NonNegInt = 0

    @field_validator("scale", mode="before")
    @classmethod
    def _scale(cls, v: Any) -> Any:
        return _check_scale(v)

    @model_validator(mode="after")
    def _growth(self) -> RestShape:
        if self.growth_steps == 0 and self.growth_rate != 0:
            raise rule_error([("growth_rate", "has no effect unless growth_steps >= 1")])
        final = 1.0 + self.growth_rate * self.growth_steps
        if final <= 0:
            raise rule_error(
                [
                    (
                        "growth_rate",
                        f"makes the rest-shape factor 1 + growth_rate * growth_steps = {final:g} <= 0 "
                        f"(need growth_rate > {-1.0 / self.growth_steps:g} for growth_steps = {self.growth_steps})",
                    )
                ]
            )
        return self

    def factor(self, step: int) -> float:
        """Growth multiplier applied to ``scale`` after ``step`` steps."""
        return 1.0 + self.growth_rate * min(step, self.growth_steps)


class FixedSelector(_Model):
    """Pins vertices selected by an axis-aligned box or by explicit indices."""

    box: list[list[Float]] | None = None
    relative: Bool = False
    indices: Annotated[list[NonNegInt], Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _one(self) -> FixedSelector:
        if (self.box is None) == (self.indices is None):
            raise rule_error([("", "give exactly one of `box` or `indices`")])
        if self.indices is not None and self.relative:
            raise rule_error([("relative", "only applies to `box`")])
        if self.box is not None:
            check_corner_box(self.box)
        return self


# ---------------------------------------------------------------------------------------------
# Procedural mesh generators (discriminated on `shape`)


class _Generator(_Model):
    """Base of the generators: ``dim`` and ``role`` ('volume' or 'surface') are class constants."""

    dim: ClassVar[int]
    role: ClassVar[str]
    shape: str

    #: most cells (tets, triangles or segments) a generator may make: ~2 GB of mesh arrays, far beyond the
    #: paper's largest meshes; a resolution of 10^5 asked numpy for petabytes (a MemoryError traceback)
    MAX_CELLS: ClassVar[int] = 10**7

    def cells(self) -> int:
        """How many cells (tets, triangles or segments) the generator makes, from its parameters."""
        return 0

    @model_validator(mode="after")
    def _size(self) -> _Generator:
        n = self.cells()
        if n > self.MAX_CELLS:
            key = next(k for k in ("resolution", "segments", "subdivisions") if k in type(self).model_fields)
            raise rule_error([(key, f"'{self.shape}' would make {n:.3g} cells, more than {self.MAX_CELLS:.0e}")])
        return self

    def params(self) -> dict[str, Any]:
        """Every generator parameter (all fields except ``shape``)."""
        return self.model_dump(exclude={"shape"})


class BallGen(_Generator):
    """Tetrahedralised ball (3D volume)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "volume"
    shape: Literal["ball"] = "ball"
    radius: PosFloat = 0.5
    center: Vec3 = [0.0, 0.0, 0.0]
    resolution: PosInt = 6

    def cells(self) -> int:
        return 6 * (2 * self.resolution) ** 3


class EllipsoidGen(_Generator):
    """Tetrahedralised ellipsoid (3D volume)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "volume"
    shape: Literal["ellipsoid"] = "ellipsoid"
    radii: PosVec3 = [0.5, 0.5, 0.5]
    center: Vec3 = [0.0, 0.0, 0.0]
    resolution: PosInt = 6

    def cells(self) -> int:
        return 6 * (2 * self.resolution) ** 3


class TetBoxGen(_Generator):
    """Tetrahedralised box (3D volume)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "volume"
    shape: Literal["tet_box"] = "tet_box"
    lo: Vec3 = [-0.5, -0.5, -0.5]
    hi: Vec3 = [0.5, 0.5, 0.5]
    resolution: Res3 = [4, 4, 4]

    def cells(self) -> int:
        return 6 * math.prod(self.resolution)

    @model_validator(mode="after")
    def _box(self) -> TetBoxGen:
        if p := _check_box(self.lo, self.hi, strict=True):
            raise rule_error(p)
        return self


class BoxSurfaceGen(_Generator):
    """Closed triangulated box surface (3D obstacle)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "surface"
    shape: Literal["box_surface"] = "box_surface"
    lo: Vec3 = [-1.0, -1.0, -1.0]
    hi: Vec3 = [1.0, 1.0, 1.0]
    resolution: PosInt = 4

    def cells(self) -> int:
        return 12 * self.resolution**2

    @model_validator(mode="after")
    def _box(self) -> BoxSurfaceGen:
        if p := _check_box(self.lo, self.hi, strict=True):
            raise rule_error(p)
        return self


class EllipsoidSurfaceGen(_Generator):
    """Closed ellipsoid surface (subdivided icosahedron), optionally with seeded radial noise (3D shell/obstacle)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "surface"
    shape: Literal["ellipsoid_surface"] = "ellipsoid_surface"
    radii: PosVec3 = [0.5, 0.5, 0.5]
    center: Vec3 = [0.0, 0.0, 0.0]
    subdivisions: Annotated[int, Strict(), Field(ge=0, le=7)] = 4
    noise: Annotated[float, Strict(), Field(ge=0, lt=0.5, allow_inf_nan=False)] = 0.0
    smoothing: Annotated[int, Strict(), Field(ge=0, le=10_000)] = 0  # passes; 10^18 was a hang (40 in Fig. 12c)
    seed: Annotated[int, Strict(), Field(ge=0)] = 0

    def cells(self) -> int:
        return 20 * 4**self.subdivisions


class CylinderSurfaceGen(_Generator):
    """Closed capped cylinder surface along y (3D obstacle)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "surface"
    shape: Literal["cylinder_surface"] = "cylinder_surface"
    radius: PosFloat = 0.5
    y0: Float = -0.5
    y1: Float = 0.5
    segments: Annotated[int, Strict(), Field(ge=3)] = 32
    rings: PosInt = 8
    cap_rings: PosInt = 3

    def cells(self) -> int:
        return 2 * self.segments * (self.rings + 2 * self.cap_rings)

    @model_validator(mode="after")
    def _ys(self) -> CylinderSurfaceGen:
        if self.y1 <= self.y0:
            raise rule_error([("y1", f"must be > y0 (got y0={self.y0}, y1={self.y1})")])
        return self


class HourglassSurfaceGen(_Generator):
    """Closed hourglass surface along y: two bulbs joined by a neck (3D obstacle)."""

    dim: ClassVar[int] = 3
    role: ClassVar[str] = "surface"
    shape: Literal["hourglass_surface"] = "hourglass_surface"
    bulb_radius: PosFloat = 0.5
    neck_radius: PosFloat = 0.15
    lower_center: Float = 0.0
    upper_center: Float = 1.6
    segments: Annotated[int, Strict(), Field(ge=3)] = 32
    rings: PosInt = 48

    def cells(self) -> int:
        return 2 * self.segments * self.rings

    @model_validator(mode="after")
    def _geom(self) -> HourglassSurfaceGen:
        probs = []
        if self.neck_radius >= self.bulb_radius:
            probs.append(("neck_radius", f"must be < bulb_radius ({self.bulb_radius}) (got {self.neck_radius})"))
        if self.upper_center <= self.lower_center:
            probs.append(("upper_center", f"must be > lower_center ({self.lower_center}) (got {self.upper_center})"))
        if probs:
            raise rule_error(probs)
        return self


class DiskGen(_Generator):
    """Triangulated disk (2D volume)."""

    dim: ClassVar[int] = 2
    role: ClassVar[str] = "volume"
    shape: Literal["disk"] = "disk"
    radius: PosFloat = 0.5
    center: Vec2 = [0.0, 0.0]
    resolution: PosInt = 6

    def cells(self) -> int:
        return 2 * (2 * self.resolution) ** 2


class RectangleGen(_Generator):
    """Triangulated rectangle (2D volume)."""

    dim: ClassVar[int] = 2
    role: ClassVar[str] = "volume"
    shape: Literal["rectangle"] = "rectangle"
    lo: Vec2 = [0.0, 0.0]
    hi: Vec2 = [1.0, 1.0]
    resolution: Res2 = [4, 4]

    def cells(self) -> int:
        return 2 * math.prod(self.resolution)

    @model_validator(mode="after")
    def _box(self) -> RectangleGen:
        if p := _check_box(self.lo, self.hi, strict=True):
            raise rule_error(p)
        return self


class CirclePolygonGen(_Generator):
    """Closed polygon approximating a circle (2D obstacle)."""

    dim: ClassVar[int] = 2
    role: ClassVar[str] = "surface"
    shape: Literal["circle_polygon"] = "circle_polygon"
    radius: PosFloat = 1.0
    center: Vec2 = [0.0, 0.0]
    segments: Annotated[int, Strict(), Field(ge=3)] = 64

    def cells(self) -> int:
        return self.segments


class BoxPolygonGen(_Generator):
    """Closed rectangular polygon (2D obstacle), ``resolution`` segments per side."""

    dim: ClassVar[int] = 2
    role: ClassVar[str] = "surface"
    shape: Literal["box_polygon"] = "box_polygon"
    lo: Vec2 = [-1.0, -1.0]
    hi: Vec2 = [1.0, 1.0]
    resolution: PosInt = 4

    def cells(self) -> int:
        return 4 * self.resolution

    @model_validator(mode="after")
    def _box(self) -> BoxPolygonGen:
        if p := _check_box(self.lo, self.hi, strict=True):
            raise rule_error(p)
        return self


GENERATORS: dict[str, type[_Generator]] = {
    cls.model_fields["shape"].default: cls
    for cls in (
        BallGen,
        EllipsoidGen,
        TetBoxGen,
        BoxSurfaceGen,
        EllipsoidSurfaceGen,
        CylinderSurfaceGen,
        HourglassSurfaceGen,
        DiskGen,
        RectangleGen,
        CirclePolygonGen,
        BoxPolygonGen,
    )
}
"""Generator model per ``shape`` name."""

Generate = Annotated[
    BallGen
    | EllipsoidGen
    | TetBoxGen
    | BoxSurfaceGen
    | EllipsoidSurfaceGen
    | CylinderSurfaceGen
    | HourglassSurfaceGen
    | DiskGen
    | RectangleGen
    | CirclePolygonGen
    | BoxPolygonGen,
    Field(discriminator="shape"),
]


def _shapes(dim: int, role: str) -> str:
    return ", ".join(s for s, c in GENERATORS.items() if c.dim == dim and c.role == role)


# ---------------------------------------------------------------------------------------------
# Objects and scene


class TetrahedralizeSpec(_Model):
    """Fill a deformable object's closed triangle surface (`mesh` an OBJ/STL/PLY/...) with tets when the scene is
    built, keeping its triangles exactly (TetGen; needs ``idp[remesh]``). ``quality``: radius-edge bound;
    ``max_volume``: largest tet volume in the file's units before placement (none = no size bound)."""

    quality: Annotated[float, Strict(), Field(ge=1.1, le=10.0)] = 1.414
    max_volume: PosFloat | None = None


class DensityRegion(_Model):
    """A region of a deformable body with its own density (paper §7.5: light flower heads on heavy stems): the
    elements whose vertices ``select`` all picks get ``density`` (later regions win where they overlap)."""

    select: SelectionSpec
    density: PosFloat


class SceneObject(_Model):
    """One mesh in the scene: a deformable body (tets in 3D, triangles in 2D), a shell (a triangle surface in 3D,
    closed or open) or a closed obstacle (static, or kinematic with ``motion``)."""

    name: Name
    kind: Literal["deformable", "shell", "obstacle"] = "deformable"
    mesh: Path | None = None
    frame: NonNegInt | None = None  # `mesh` is an animation sequence (npz, PVD, USD, OBJ folder/glob): this frame
    generate: Generate | None = None
    scale: Scale = 1.0
    rotate: list[Rotation] = Field(default_factory=list)
    translate: list[Float] | None = None  # filled with zeros (dim entries) by Scene
    material: Material | None = None  # filled with Material() for deformables
    shell: ShellMaterial | None = None  # filled by Scene: ShellMaterial() (or no elasticity in a flow)
    fix_boundary: Bool | None = None  # shells: pin the boundary vertices of open surfaces (default: no; flows: yes)
    # 2D deformables: `mesh` is an OBJ with texture coordinates; the simulated nodes are its vt coordinates, the
    # elements its UV-indexed triangles and the rest metric that of the corresponding 3D triangles (paper §7.4)
    uv: Bool = False
    rest_shape: RestShape | None = None  # filled with RestShape() for deformables
    fixed: list[FixedSelector] = Field(default_factory=list)
    handles: list[HandleSpec] = Field(default_factory=list)
    motion: KinematicSpec | None = None  # obstacles only: a kinematic (moving) obstacle
    plasticity: PlasticitySpec | None = None
    density_regions: list[DensityRegion] = Field(default_factory=list)  # per-region density (deformables)
    tetrahedralize: TetrahedralizeSpec | None = None  # deformables from a closed surface file
    material_stages: list[MaterialStageSpec] = Field(default_factory=list)
    rest_scripts: list[RestScriptSpec] = Field(default_factory=list)
    # deformables: rest frames (and plastic state) saved by an earlier stage (.npz), in place of `mesh`'s shape
    rest_state: Path | None = None
    # copies of this object, each its own body `{name}_{k}` (expanded by Scene; idp/scene/layout_schema.py)
    instances: InstancesSpec | None = None
    instance_transform: InstanceTransform | None = None  # one copy's map, after scale/rotate/translate

    @field_validator("scale", mode="before")
    @classmethod
    def _scale(cls, v: Any) -> Any:
        return _check_scale(v)

    @model_validator(mode="after")
    def _rules(self) -> SceneObject:
        probs: list[tuple[str, str]] = []
        if self.mesh is None and self.generate is None:
            probs.append(("mesh", "give exactly one of `mesh` (a file) or `generate` (a procedural shape)"))
        elif self.mesh is not None and self.generate is not None:
            probs.append(("generate", "give either `mesh` or `generate`, not both"))
        if self.kind != "shell":
            for key in ("shell", "fix_boundary"):
                if getattr(self, key) is not None:
                    probs.append((key, 'only allowed on shell objects (kind = "shell")'))
        if self.kind == "shell":
            for key in ("material", "rest_shape", "plasticity", "motion"):
                if getattr(self, key) is not None:
                    what = "give a shell's material as `shell`" if key == "material" else "not supported on shells"
                    probs.append((key, what))
            for key in ("material_stages", "rest_scripts"):
                if getattr(self, key):
                    probs.append((key, "not supported on shells"))
        if self.tetrahedralize is not None and (self.kind != "deformable" or self.mesh is None or self.uv):
            probs.append(("tetrahedralize", "only for a deformable object whose `mesh` is a closed triangle surface"))
        if self.density_regions and self.kind != "deformable":
            probs.append(("density_regions", "only for deformable (volume) objects; a shell's density is `shell`'s"))
        if self.rest_state is not None and (self.kind != "deformable" or self.uv):
            probs.append(("rest_state", "only for deformable (volume) objects"))
        if self.uv and (self.kind != "deformable" or self.mesh is None or self.frame is not None):
            probs.append(("uv", "only for a deformable object whose `mesh` is an OBJ file with texture coordinates"))
        if self.kind == "obstacle":
            for key in ("material", "rest_shape"):
                if getattr(self, key) is not None:
                    probs.append((key, "only allowed on deformable objects (this object is an obstacle)"))
            if self.fixed:
                probs.append(("fixed", "only allowed on deformable objects (obstacles are fixed entirely)"))
            if self.handles:
                probs.append(("handles", "only allowed on deformable objects (move an obstacle with `motion`)"))
            for key in ("plasticity",):
                if getattr(self, key) is not None:
                    probs.append((key, "only allowed on deformable objects"))
            for key in ("material_stages", "rest_scripts"):
                if getattr(self, key):
                    probs.append((key, "only allowed on deformable objects"))
        elif self.motion is not None:
            probs.append(("motion", "only allowed on obstacles (drive a deformable object with `handles`)"))
        starts = [st.start for st in self.material_stages]
        if any(b <= a for a, b in itertools.pairwise(starts)):
            probs.append(("material_stages", f"start steps must increase strictly (got {starts})"))
        counts = collections.Counter(h.name for h in self.handles)  # linear: a file may list 10^5 handles
        dup = sorted(n for n, c in counts.items() if c > 1)
        if dup:
            probs.append(("handles", f"duplicate handle name {dup[0]!r}"))
        if self.generate is not None:
            gen = self.generate
            want = "volume" if self.kind == "deformable" else "surface"
            if self.kind == "shell" and gen.role != "surface":
                probs.append(("generate.shape", f"'{gen.shape}' makes a volume mesh; a shell needs a surface"))
            # an obstacle may also be generated as a solid (ball, ellipsoid, box, disk): its boundary is used
            if gen.role != want and want == "volume":
                what = "a volume mesh" if gen.role == "volume" else "a closed surface/polygon"
                probs.append(
                    (
                        "generate.shape",
                        f"'{gen.shape}' makes {what}; "
                        f"{'a deformable' if want == 'volume' else 'an obstacle'} needs one of: "
                        f"{_shapes(3, want)} (3D), {_shapes(2, want)} (2D)",
                    )
                )
        if probs:
            raise rule_error(probs)
        if self.kind == "deformable":
            if self.material is None:
                self.material = Material()
            if self.rest_shape is None:
                self.rest_shape = RestShape()
        return self


def _selection_vectors(path: str, sel: SelectionSpec, vec: Callable[[str, list[float] | None], None]) -> None:
    """Dimension checks of a selection's box corners and sphere centre, and of its ``exclude``."""
    if sel.box is not None:
        vec(f"{path}.box[0]", sel.box[0])
        vec(f"{path}.box[1]", sel.box[1])
    if sel.sphere is not None:
        vec(f"{path}.sphere.center", sel.sphere.center)
    if sel.exclude is not None:
        _selection_vectors(f"{path}.exclude", sel.exclude, vec)


def _motion_vectors(path: str, m: MotionSpec, d: int, probs: list[tuple[str, str]]) -> None:
    """Dimension checks of a motion's vectors (lengths d; rotation axis only in 3D)."""

    def vec(key: str, v: list[float] | None) -> None:
        if v is not None and len(v) != d:
            probs.append((f"{path}.{key}", f"must have {d} entries for dim = {d} (got {len(v)})"))

    vec("velocity", m.velocity)
    vec("center", m.center)
    if m.type == "roll":
        if d != 3:
            probs.append((f"{path}.type", "'roll' is a 3D motion"))
        else:
            vec("axis", m.axis)
            vec("direction", m.direction)
            a, u = m.axis or [], m.direction or []
            if len(a) == 3 and len(u) == 3:
                an, un = math.sqrt(sum(v * v for v in a)), math.sqrt(sum(v * v for v in u))
                dot = abs(sum(x * y for x, y in zip(a, u, strict=True)))
                if an == 0 or un == 0 or dot >= (1 - 1e-9) * an * un:
                    probs.append((f"{path}.direction", "must be non-zero and not parallel to `axis`"))
    vec("offset", m.offset)
    if isinstance(m.rate, list):
        vec("rate", m.rate)
    if m.type == "rotate":
        if d == 3 and m.axis is None:
            probs.append((f"{path}.axis", "required in 3D"))
        elif d == 2 and m.axis is not None:
            probs.append((f"{path}.axis", "must be omitted in 2D (rotation is in the plane)"))
        elif m.axis is not None:
            vec("axis", m.axis)
            if not any(a != 0 for a in m.axis):
                probs.append((f"{path}.axis", "must be non-zero"))
    for j, k in enumerate(m.keyframes or []):
        vec(f"keyframes[{j}].translate", k.translate)
        if isinstance(k.scale, list):
            vec(f"keyframes[{j}].scale", k.scale)
        if k.rotate is not None:
            if d == 3 and k.rotate.axis is None and k.rotate.degrees != 0:
                probs.append((f"{path}.keyframes[{j}].rotate.axis", "required in 3D"))
            elif d == 2 and k.rotate.axis is not None:
                probs.append((f"{path}.keyframes[{j}].rotate.axis", "must be omitted in 2D"))
            elif k.rotate.axis is not None:
                vec(f"keyframes[{j}].rotate.axis", k.rotate.axis)


class Scene(_Model):
    """A complete scene: global settings plus objects."""

    name: Name = "scene"
    dim: Literal[2, 3] = 3
    time: TimeConfig = Field(default_factory=TimeConfig)
    solver: SolverConfig = Field(default_factory=SolverConfig)
    contact: ContactConfig = Field(default_factory=ContactConfig)
    output: OutputConfig = Field(default_factory=OutputConfig)
    dirichlet: DirichletConfig = Field(default_factory=DirichletConfig)
    flow: FlowConfig | None = None
    repair: RepairConfig | None = None
    gravity: list[Float] | None = None  # body force per unit mass (e.g. [0, -9.8, 0]); none = no gravity
    sticky: StickyConfig | None = None  # opt-in weak springs between close bodies (outside the paper's energy)
    objects: list[SceneObject] = Field(default_factory=list)
    stages: list[StageSpec] = Field(default_factory=list)  # a multi-stage modeling scene (§7.5)

    @model_validator(mode="after")
    def _rules(self) -> Scene:
        d = self.dim
        probs: list[tuple[str, str]] = []

        def vec(path: str, v: list[float] | None) -> None:
            if v is not None and len(v) != d:
                probs.append((path, f"must have {d} entries for dim = {d} (got {len(v)})"))

        if self.repair is not None:
            self._repair_object(probs)
        seen: dict[str, int] = {}
        for i, ob in enumerate(self.objects):
            p = f"objects[{i}]"
            if ob.name in seen:
                probs.append((f"{p}.name", f"duplicate name '{ob.name}' (also used by objects[{seen[ob.name]}])"))
            else:
                seen[ob.name] = i
            if isinstance(ob.scale, list):
                vec(f"{p}.scale", ob.scale)
            vec(f"{p}.translate", ob.translate)
            for j, rot in enumerate(ob.rotate):
                if d == 2 and rot.axis is not None:
                    probs.append((f"{p}.rotate[{j}].axis", "must be omitted in 2D (rotation is in the plane)"))
                elif d == 3 and rot.axis is None:
                    probs.append((f"{p}.rotate[{j}].axis", "required in 3D"))
                else:
                    vec(f"{p}.rotate[{j}].axis", rot.axis)
            if ob.rest_shape is not None and isinstance(ob.rest_shape.scale, list):
                vec(f"{p}.rest_shape.scale", ob.rest_shape.scale)
            for j, sel in enumerate(ob.fixed):
                if sel.box is not None:
                    vec(f"{p}.fixed[{j}].box[0]", sel.box[0])
                    vec(f"{p}.fixed[{j}].box[1]", sel.box[1])
            for j, hd in enumerate(ob.handles):
                q = f"{p}.handles[{j}]"
                _selection_vectors(f"{q}.select", hd.select, vec)
                _motion_vectors(f"{q}.motion", hd.motion, d, probs)
            if ob.motion is not None:
                _motion_vectors(f"{p}.motion.motion", ob.motion.motion, d, probs)
            for j, reg in enumerate(ob.density_regions):
                _selection_vectors(f"{p}.density_regions[{j}].select", reg.select, vec)
            for j, rs in enumerate(ob.rest_scripts):
                if isinstance(rs.rate, list):
                    vec(f"{p}.rest_scripts[{j}].rate", rs.rate)
                if rs.region is not None:
                    _selection_vectors(f"{p}.rest_scripts[{j}].region", rs.region, vec)
            if ob.generate is not None and ob.generate.dim != d:
                probs.append(
                    (
                        f"{p}.generate.shape",
                        f"'{ob.generate.shape}' is a {ob.generate.dim}D shape but dim = {d}",
                    )
                )
            if ob.kind == "shell" and d != 3:
                probs.append((f"{p}.kind", "shells are triangle surfaces in 3D (dim = 3)"))
            if ob.uv and d != 2:
                probs.append((f"{p}.uv", "a UV map is simulated in its 2D texture plane (dim = 2)"))
        self.objects, layout_probs = expand_instances(self.objects, d)  # checked above in the file's numbering
        probs.extend(layout_probs)
        vec("gravity", self.gravity)
        check_stages(self, probs)
        check_sticky(self, probs)
        if not any(ob.kind in ("deformable", "shell") for ob in self.objects) and not self.stages:
            probs.append(("objects", "at least one deformable or shell object is required"))
        if self.flow is not None and not any(ob.kind == "shell" for ob in self.objects):
            probs.append(("flow", 'a normal flow moves shell objects (kind = "shell"); the scene has none'))
        if probs:
            raise rule_error(probs)
        if self.flow is not None:
            # a flow's step moves ~|β|: a stopping rule in those units unless the scene gives its own
            if "newton_tol" not in self.solver.model_fields_set:
                self.solver.newton_tol = FLOW_TOL_FRACTION * abs(self.flow.beta)
            if "newton_norm" not in self.solver.model_fields_set:
                self.solver.newton_norm = "rms"
        for ob in self.objects:
            if ob.kind == "shell" and ob.shell is None:
                # in a flow, the paper's shells: no elastic energy, density 1, thickness 1
                ob.shell = (
                    ShellMaterial()
                    if self.flow is None
                    else ShellMaterial(youngs_modulus=0.0, bending=0.0, density=1.0, thickness=1.0)
                )
        for ob in self.objects:
            if ob.translate is None:
                ob.translate = [0.0] * d
        return self

    def _repair_object(self, probs: list[tuple[str, str]]) -> None:
        """A repair scene's one shell object is its input sequence (made here when ``objects`` is left out), and
        its contact and stopping rule default to the authors' set-up."""
        r = self.repair
        assert r is not None
        if self.dim != 3:
            probs.append(("repair", "animation repair works on triangle surfaces in 3D (dim = 3)"))
        if self.flow is not None:
            probs.append(("flow", "a scene is either a normal flow or an animation repair, not both"))
        if not self.objects:
            self.objects = [
                SceneObject(
                    name="surface",
                    kind="shell",
                    mesh=r.input,
                    frame=r.start,
                    shell=ShellMaterial(
                        youngs_modulus=100.0, poisson_ratio=0.4, thickness=0.01, bending=1.0, density=1000.0
                    ),
                )
            ]
        elif len(self.objects) != 1 or self.objects[0].kind != "shell" or self.objects[0].mesh != r.input:
            probs.append(
                ("objects", "a repair scene has one shell object whose `mesh` is repair.input (or leave it out)")
            )
        else:
            ob = self.objects[0]
            if ob.frame not in (None, r.start):
                probs.append(("objects[0].frame", f"must be repair.start = {r.start} (the first frame repaired)"))
            ob.frame = r.start
            if ob.shell is None:
                ob.shell = ShellMaterial(
                    youngs_modulus=100.0, poisson_ratio=0.4, thickness=0.01, bending=1.0, density=1000.0
                )
        shell = self.objects[0].shell if len(self.objects) == 1 else None
        if shell is not None and "bending_hessian" not in shell.model_fields_set:
            # a repaired frame stays near its input, the bending's rest shape: the Gauss–Newton Hessian serves
            # as well as the projected one there, at a tenth of its cost (docs/animation-repair.md)
            shell.bending_hessian = REPAIR_BENDING_HESSIAN
        if "dhat" not in self.contact.model_fields_set:
            self.contact.dhat = REPAIR_DHAT
        if "newton_tol" not in self.solver.model_fields_set:
            self.solver.newton_tol = REPAIR_NEWTON_TOL
        if "kappa_init" not in self.contact.model_fields_set:
            self.contact.kappa_init = "once"
        if "newton_norm" not in self.solver.model_fields_set:
            self.solver.newton_norm = "rms"
        if r.first_frame == "preserve":
            self.contact.preserve_input_intersections = True

    def object(self, name: str) -> SceneObject:
        """The object called ``name`` (KeyError if none)."""
        for ob in self.objects:
            if ob.name == name:
                return ob
        raise KeyError(name)


_MODEL_CLASSES: tuple[type[BaseModel], ...] = (
    Scene,
    SceneObject,
    DensityRegion,
    TetrahedralizeSpec,
    StickyConfig,
    TimeConfig,
    SolverConfig,
    ContactConfig,
    OutputConfig,
    Material,
    ShellMaterial,
    FlowConfig,
    RepairConfig,
    RepairSelector,
    RestShape,
    FixedSelector,
    Rotation,
    SelectionSpec,
    SphereSpec,
    MotionSpec,
    KeyframeSpec,
    RotationSpec,
    HandleSpec,
    KinematicSpec,
    DirichletConfig,
    PlasticitySpec,
    MaterialStageSpec,
    RestScriptSpec,
    StageSpec,
    StageObjectSettings,
    AnchorSpec,
    RemeshSpec,
    InstancesSpec,
    TransformSpec,
    GridSpec,
    RingSpec,
    RandomSpec,
    InstanceTransform,
    *GENERATORS.values(),
)
# the stage models name these classes; complete them now that they exist
_STAGE_NAMES = {
    "Material": Material,
    "SceneObject": SceneObject,
    "FixedSelector": FixedSelector,
    "ShellMaterial": ShellMaterial,
}
StageObjectSettings.model_rebuild(_types_namespace=_STAGE_NAMES)
StageSpec.model_rebuild(_types_namespace=_STAGE_NAMES)
Scene.model_rebuild()

MODELS: dict[str, type[BaseModel]] = {c.__name__: c for c in _MODEL_CLASSES}
"""Every scene model by class name (used to interpret error locations)."""
