"""Scene-file models of multi-stage modeling scenes (paper §4.5 bake and remesh, §7.5 modeling and layout).

::

    [[stages]]
    name = "compress"
    steps = 30
    [stages.set.dough]                       # per-object settings for this stage
    plasticity = { yield_stress = 1e4 }
    [stages.after]
    dough = "bake_remesh"                    # at the end: bake, then re-tetrahedralise keeping the surface

    [[stages]]
    name = "fold"
    steps = 13
    remove = ["top_plate"]
    [[stages.add]]                           # a new object, placed relative to a current shape
    name = "filling"
    generate = { shape = "ellipsoid", radii = [0.3, 0.2, 0.3] }
    [stages.anchor.filling]
    object = "dough"
    at = [0.5, 1.0, 0.5]                     # the dough's current bbox: 0 = min, 1 = max per axis

Rules (checked by :class:`idp.scene.schema.Scene`, naming the stage and key): materials, plasticity and shell
materials persist from the stage that sets them; handles, fixed selections, obstacle motions, rest scripts and
material stages belong to the stage they are written in (an object's top-level ones to the first stage only).
Every stage starts from the shapes, rest state and plastic state the previous one ended with (``after``:
``carry``, the default), or with the current shape as the rest shape (``bake``), or re-tetrahedralised
(``remesh``, rest and plastic state transferred; ``bake_remesh``: bake, then re-tetrahedralise).

The models refer to :class:`~idp.scene.schema.Material`, ``SceneObject``, ... by name; ``idp.scene.schema``
completes them (``model_rebuild``) once those exist.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, Strict, model_validator

from idp.scene.conditions_schema import (
    HandleSpec,
    KinematicSpec,
    MaterialStageSpec,
    PlasticitySpec,
    RestScriptSpec,
)
from idp.scene.schema_base import Bool, Float, Name, PosFloat, PosInt, _Model, rule_error

if TYPE_CHECKING:  # completed at runtime by idp.scene.schema
    from idp.scene.schema import FixedSelector, Material, SceneObject
    from idp.scene.shell_schema import ShellMaterial

AFTER_STAGE = ("carry", "bake", "remesh", "bake_remesh")


class RemeshSpec(_Model):
    """Surface-preserving re-tetrahedralisation at the end of a stage (paper §4.5; needs ``idp[remesh]``).

    ``quality``: TetGen's radius-edge bound (smaller = better shaped, more elements); ``max_volume``: largest
    tet volume (scene units³; none = no size bound); ``refine_surface``: let boundary triangles be split in their
    own plane (the surface as a point set is kept, its triangulation refined); ``if_unavailable``: what a
    remesh request does when the mesher is not installed: ``error`` (before any stage runs) or ``skip`` (warn
    and carry the mesh on)."""

    quality: Annotated[float, Strict(), Field(ge=1.1, le=10.0)] = 1.414
    max_volume: PosFloat | None = None
    refine_surface: Bool = False
    if_unavailable: Literal["error", "skip"] = "error"


class StageObjectSettings(_Model):
    """What one object does in one stage. ``material``, ``plasticity`` and ``shell`` persist to later stages;
    the rest applies to this stage only."""

    material: Material | None = None
    plasticity: PlasticitySpec | None = None
    shell: ShellMaterial | None = None
    handles: list[HandleSpec] | None = None
    fixed: list[FixedSelector] | None = None
    motion: KinematicSpec | None = None
    rest_scripts: list[RestScriptSpec] | None = None
    material_stages: list[MaterialStageSpec] | None = None


class AnchorSpec(_Model):
    """Place an added object relative to a current shape: its placed position is translated by the point
    ``at`` (bbox-relative: 0 = min, 1 = max per axis) of ``object``'s shape at the start of the stage."""

    object: Name
    at: list[Float]


class StageSpec(_Model):
    """One stage of a modeling scene: its own steps, per-object settings, added/removed objects and what happens
    to each object when it ends."""

    name: Name
    steps: PosInt
    h: PosFloat | None = None  # time.h for this stage (default: the scene's)
    dhat: PosFloat | None = None  # contact.dhat for this stage, in the scene's dhat_mode
    gravity: list[Float] | None = None  # body force for this stage (default: the scene's `gravity`)
    newton_tol: PosFloat | None = None  # solver.newton_tol for this stage
    objects: list[Name] | None = None  # which objects take part (default: every object present)
    remove: list[Name] = Field(default_factory=list)  # removed before this stage (for good)
    add: list[SceneObject] = Field(default_factory=list)  # added at the start of this stage
    anchor: dict[str, AnchorSpec] = Field(default_factory=dict)  # placement of added objects
    set: dict[str, StageObjectSettings] = Field(default_factory=dict)
    after: dict[str, Literal["carry", "bake", "remesh", "bake_remesh"]] = Field(default_factory=dict)
    remesh: RemeshSpec = Field(default_factory=RemeshSpec)

    @model_validator(mode="after")
    def _local(self) -> StageSpec:
        probs = []
        added = {ob.name for ob in self.add}
        for name in self.anchor:
            if name not in added:
                probs.append((f"anchor.{name}", "anchors place objects added by this stage (`add`)"))
        for name, a in self.anchor.items():
            if a.object == name:
                probs.append((f"anchor.{name}.object", "an object cannot be anchored to itself"))
        if probs:
            raise rule_error(probs)
        return self

    def uses_remesh(self) -> bool:
        return any(v in ("remesh", "bake_remesh") for v in self.after.values())


def check_stages(scene, probs: list[tuple[str, str]]) -> None:
    """Rules of a scene's stage list that need the objects: names known when used, kinds that fit each key,
    vector lengths, remeshing only of 3D volumes. Appends ``(key path, message)`` to ``probs``."""
    if not scene.stages:
        return
    from idp.scene.schema import _motion_vectors  # the checks every object's motions get

    d = scene.dim
    if scene.repair is not None or scene.flow is not None:
        probs.append(("stages", "stages are for modeling scenes, not a normal flow or an animation repair"))
    kinds = {ob.name: ob.kind for ob in scene.objects}
    alive = set(kinds)
    seen_stage: dict[str, int] = {}
    for k, st in enumerate(scene.stages):
        p = f"stages[{k}]"
        if st.name in seen_stage:
            probs.append((f"{p}.name", f"duplicate stage name {st.name!r} (also stages[{seen_stage[st.name]}])"))
        seen_stage.setdefault(st.name, k)
        if st.gravity is not None and len(st.gravity) != d:
            probs.append((f"{p}.gravity", f"must have {d} entries for dim = {d} (got {len(st.gravity)})"))
        for j, name in enumerate(st.remove):
            if name not in alive:
                probs.append((f"{p}.remove[{j}]", f"no object {name!r} is present at this stage"))
            alive.discard(name)
        for j, ob in enumerate(st.add):
            if ob.name in alive:
                probs.append((f"{p}.add[{j}].name", f"an object {ob.name!r} is already present"))
            kinds[ob.name] = ob.kind
            alive.add(ob.name)
            if ob.generate is not None and ob.generate.dim != d:
                probs.append(
                    (f"{p}.add[{j}].generate.shape", f"'{ob.generate.shape}' is {ob.generate.dim}D, dim = {d}")
                )
        for name, a in st.anchor.items():
            if a.object not in alive:
                probs.append((f"{p}.anchor.{name}.object", f"no object {a.object!r} is present at this stage"))
            if len(a.at) != d:
                probs.append((f"{p}.anchor.{name}.at", f"must have {d} entries for dim = {d} (got {len(a.at)})"))
        taking = set(alive) if st.objects is None else set(st.objects)
        for j, name in enumerate(st.objects or []):
            if name not in alive:
                probs.append((f"{p}.objects[{j}]", f"no object {name!r} is present at this stage"))
        if not any(kinds.get(n) in ("deformable", "shell") for n in taking & alive):
            key = f"{p}.objects" if st.objects is not None else p
            probs.append((key, "no deformable or shell object takes part in this stage"))
        for name, s in st.set.items():
            q = f"{p}.set.{name}"
            if name not in alive:
                probs.append((q, f"no object {name!r} is present at this stage"))
                continue
            kind = kinds[name]
            if kind == "obstacle":
                for key in ("material", "plasticity", "shell", "handles", "fixed", "rest_scripts", "material_stages"):
                    if getattr(s, key) is not None:
                        probs.append((f"{q}.{key}", f"{name!r} is an obstacle (move it with `motion`)"))
            else:
                if s.motion is not None:
                    probs.append((f"{q}.motion", f"{name!r} is not an obstacle (drive it with `handles`)"))
                bad = ("material", "plasticity", "rest_scripts", "material_stages") if kind == "shell" else ("shell",)
                for key in bad:
                    if getattr(s, key) is not None:
                        probs.append((f"{q}.{key}", f"not used by a {kind} object"))
            if s.motion is not None:
                _motion_vectors(f"{q}.motion.motion", s.motion.motion, d, probs)
            for j, hd in enumerate(s.handles or []):
                _motion_vectors(f"{q}.handles[{j}].motion", hd.motion, d, probs)
        for name, what in st.after.items():
            q = f"{p}.after.{name}"
            if name not in alive:
                probs.append((q, f"no object {name!r} is present at this stage"))
            elif what != "carry" and kinds[name] != "deformable":
                probs.append((q, f"{what!r} applies to deformable (volume) objects; {name!r} is a {kinds[name]}"))
            elif what in ("remesh", "bake_remesh") and d != 3:
                probs.append((q, "remeshing re-tetrahedralises 3D volumes (dim = 3)"))
            elif what != "carry" and name not in taking:
                probs.append((q, f"{name!r} does not take part in this stage"))
