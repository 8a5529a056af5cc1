"""Multi-stage modeling scenes (paper §4.5 bake and remesh, §7.5 modeling and layout) as a thin driver.

A staged scene is run as one ordinary run per stage, each through :func:`idp.api.run_built` (the shared
Newton loop, certificate, writers, statistics and checkpoint) into ``OUT/stages/NN_name/``. Between stages
every object's end state is written to that folder's ``state/`` (shape as VTU; rest frames, rest volumes
and plastic strain as .npz, after the stage's ``bake`` / ``remesh`` / ``carry``), and the next stage is an
ordinary scene whose objects read those files (``mesh`` + ``rest_state``). So a stage is reproducible alone
from its ``scene.resolved.toml``, and a staged run equals running its stages one after the other.

A stage is marked done by ``stage.json`` (written last, atomically). ``resume=True`` skips the done stages,
resumes the interrupted one from its checkpoint and goes on: a failing stage leaves every earlier stage's
outputs intact and resumable.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from idp._faults import kill_point
from idp.errors import IdpError, SceneError
from idp.fs import check_output_dir, make_output_dir
from idp.mesh.types import SurfaceMesh, VolumeMesh
from idp.scene.load import dump_scene_toml, resolved_scene_dict
from idp.scene.resume_check import check_resume_scene
from idp.scene.schema import Scene, SceneObject
from idp.scene.stages_schema import StageSpec
from idp.stepper.stage_state import write_rest_state, write_shape

log = logging.getLogger("idp")

#: keys of a stage's per-object settings that persist to later stages (the others hold for one stage)
PERSISTENT_KEYS = ("material", "plasticity", "shell")
STAGE_ONLY_KEYS = ("handles", "fixed", "motion", "rest_scripts", "material_stages")
#: placement keys of an object spec, reset once its shape comes from a stage's state file
PLACEMENT_KEYS = ("generate", "frame", "scale", "rotate", "translate", "instance_transform")


@dataclass
class ObjectState:
    """Where an object's current shape and rest state are, and its spec for the next stage it takes part in."""

    spec: SceneObject  # the persistent settings (material, plasticity, shell) and, before any stage, placement
    first_stage: int  # the stage it was added at (its top-level stage-only keys apply there)
    mesh: Path | None = None  # its shape at the end of the last stage it took part in (None: not run yet)
    rest_state: Path | None = None


@dataclass
class StagedResult:
    """What a staged run produced: one summary per stage, the final positions per object and the output folder."""

    out_dir: Path
    stages: list[dict] = field(default_factory=list)
    final_shapes: dict[str, Path] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    @property
    def all_certified(self) -> bool:
        return all(s.get("all_certified", False) for s in self.stages)


def _render_final(scene: Scene, states: dict[str, ObjectState], shapes: dict[str, Path], path: Path) -> None:
    """The final render: every deformable object's last shape seen from above, the side and the end (3D), or the
    plane (2D). Obstacles (the tools) are left out; a picture never fails a finished run."""
    import meshio

    from idp.mesh.surface import boundary_faces
    from idp.output.parts import Part
    from idp.output.render import render_frames_png
    from idp.scene.build import picture_up_axis

    try:
        parts, xs, n = [], [], 0
        for name, target in shapes.items():
            if states[name].spec.kind == "obstacle":
                continue
            m = meshio.read(target)
            cells = {c.type: c.data.astype(np.int64) for c in m.cells}
            pts = np.asarray(m.points, dtype=np.float64)[:, : scene.dim]
            ids = np.arange(n, n + len(pts))
            if "tetra" in cells or (scene.dim == 2 and "triangle" in cells):
                el = cells["tetra"] if scene.dim == 3 else cells["triangle"]
                parts.append(Part(name, "deformable", ids, el + n, boundary_faces(el) + n))
            elif "triangle" in cells:  # a shell
                parts.append(Part(name, "shell", ids, None, cells["triangle"] + n))
            else:
                continue
            xs.append(pts)
            n += len(pts)
        if not parts:
            return
        x = np.concatenate(xs)
        if scene.dim == 3:
            parts = _visible_parts(parts, x)
        if scene.dim == 3:
            up = picture_up_axis(scene)
            frames = [("from above", x), ("oblique", x), ("from the side", x)]
            render_frames_png(
                path, parts, frames, dim=3, up=up, views=[(70.0, -90.0), (15.0, -60.0), (15.0, 0.0)], size=(1500, 500)
            )
        else:
            render_frames_png(path, parts, [("final", x)], dim=2, size=(800, 600))
    except Exception as exc:  # a picture must never lose a finished run
        log.warning("could not render final.png: %s", exc)


def _visible_parts(parts: list, x: np.ndarray) -> list:
    """Leave out of a 3D picture the bodies shut inside another (a dumpling's filling in its wrapper): hidden
    anyway, and drawn they show through thin walls where the painter's depth sort of near-touching surfaces
    misorders faces."""
    from idp.mesh.containment import shielded

    keep = []
    surface_ids = [np.unique(p.surface) for p in parts]
    boxes = [(x[ids].min(axis=0), x[ids].max(axis=0)) for ids in surface_ids]
    for i, p in enumerate(parts):
        ids = surface_ids[i]
        sample = x[ids[:: max(1, ids.size // 64)]]
        hidden = any(
            q.kind == "deformable"
            and j != i
            and bool(np.all(boxes[j][0] <= boxes[i][0]) and np.all(boxes[i][1] <= boxes[j][1]))  # cheap test first
            and bool(np.all(shielded(sample, x, q.surface)))
            for j, q in enumerate(parts)
        )
        if not hidden:
            keep.append(p)
    return keep or parts


def _stage_index(scene: Scene, stage: int | str | None) -> int | None:
    """The index of a stage given by index or name (``stop_after``); an unknown one is an error listing them."""
    if stage is None:
        return None
    names = [s.name for s in scene.stages]
    listed = ", ".join(f"{k} ({n})" for k, n in enumerate(names))
    if isinstance(stage, str) and not stage.isdigit():
        if stage not in names:
            raise SceneError(f"stop_after: no stage named {stage!r}; the stages are {listed}")
        return names.index(stage)
    k = int(stage)
    if not 0 <= k < len(names):
        raise SceneError(f"stop_after: stage index {k} is out of range; the stages are {listed}")
    return k


def _stage_dir(out: Path, k: int, stage: StageSpec) -> Path:
    return out / "stages" / f"{k:02d}_{stage.name}"


def _check_mesher(scene: Scene) -> None:
    """Remesh requests without the mesher: an error naming the stage and the extra, before anything runs (or a
    warning when the stage says ``if_unavailable = "skip"``)."""
    if not any(st.uses_remesh() for st in scene.stages):
        return
    from idp.mesh.remesh import mesher_available

    if mesher_available():
        return
    for k, st in enumerate(scene.stages):
        for name, what in st.after.items():
            if what in ("remesh", "bake_remesh") and st.remesh.if_unavailable == "error":
                raise SceneError(
                    f"stages[{k}] ({st.name}).after.{name} = {what!r}: surface-preserving remeshing needs the "
                    'optional mesher; install it with pip install "idp[remesh]" '
                    '(or set stages[k].remesh.if_unavailable = "skip")'
                )


def _spec_dict(ob: SceneObject) -> dict[str, Any]:
    return ob.model_dump(exclude_none=True)


def _stage_object(state: ObjectState, stage: StageSpec, k: int) -> SceneObject:
    """The object as an ordinary scene object of stage ``k``: its current shape and rest state, its persistent
    settings and this stage's handles/motion/fixed/scripts."""
    d = _spec_dict(state.spec)
    for key in STAGE_ONLY_KEYS:  # the top-level ones belong to the stage the object starts in
        if k != state.first_stage:
            d.pop(key, None)
    settings = stage.set.get(state.spec.name)
    if settings is not None:
        given = settings.model_dump(exclude_none=True, include=set(STAGE_ONLY_KEYS))
        d.update(given)
    if state.mesh is not None:
        for key in PLACEMENT_KEYS:
            d.pop(key, None)
        d["mesh"] = state.mesh
        if state.rest_state is not None:
            d["rest_state"] = state.rest_state
    return SceneObject.model_validate(d)


def _persist(state: ObjectState, stage: StageSpec) -> None:
    """Fold this stage's persistent settings (material, plasticity, shell) into the object's spec."""
    settings = stage.set.get(state.spec.name)
    if settings is None:
        return
    upd = {key: getattr(settings, key) for key in PERSISTENT_KEYS if getattr(settings, key) is not None}
    if upd:
        state.spec = state.spec.model_copy(update=upd)


def _current_vertices(scene: Scene, state: ObjectState) -> np.ndarray:
    """An object's current vertex positions: its last stage's shape, or its placed input."""
    from idp.mesh.io import read_mesh
    from idp.scene.build import _load_object_mesh, _place

    if state.mesh is not None:
        return read_mesh(state.mesh, kind="volume" if state.spec.kind == "deformable" else "surface").vertices
    mesh = _load_object_mesh(state.spec, scene.dim)
    return _place(state.spec, mesh.vertices, scene.dim)


def _anchored(scene: Scene, ob: SceneObject, anchor, states: dict[str, ObjectState]) -> SceneObject:
    """``ob`` translated by the anchor point of another object's current bounding box."""
    v = _current_vertices(scene, states[anchor.object])
    lo, hi = v.min(axis=0), v.max(axis=0)
    point = lo + np.asarray(anchor.at, dtype=float) * (hi - lo)
    t = np.asarray(ob.translate if ob.translate is not None else np.zeros(scene.dim), dtype=float) + point
    return ob.model_copy(update={"translate": [float(c) for c in t]})


def _stage_scene(scene: Scene, stage: StageSpec, k: int, objects: list[SceneObject], out: Path) -> Scene:
    """Stage ``k`` as an ordinary (single-stage) scene writing into ``out``."""
    base = scene.model_dump(exclude_none=True, exclude={"stages", "objects"})
    base["name"] = f"{scene.name}.{stage.name}"
    base["time"] = {**base.get("time", {}), "steps": stage.steps}
    if stage.h is not None:
        base["time"]["h"] = stage.h
    if stage.newton_tol is not None:
        base.setdefault("solver", {})["newton_tol"] = stage.newton_tol
    if stage.dhat is not None:
        base.setdefault("contact", {})["dhat"] = stage.dhat
    if stage.gravity is not None:
        base["gravity"] = stage.gravity
    base.setdefault("output", {})["dir"] = out
    base["objects"] = objects
    if scene.sticky is not None:  # links among this stage's objects only; none when too few take part
        present = scene.sticky.matches([ob.name for ob in objects])
        if len(present) >= scene.sticky.min_bodies:
            base["sticky"]["bodies"] = present
        else:
            base.pop("sticky", None)
    return Scene.model_validate(base)


def _deformable_end_state(
    body, plasticity, x_body: np.ndarray, elements: np.ndarray, what: str, stage: StageSpec
) -> tuple[VolumeMesh, np.ndarray, np.ndarray, np.ndarray | None, dict]:
    """A body's end shape and rest state after ``what`` (carry / bake / remesh / bake_remesh), local numbering.

    Returns (mesh, rest frames Dm, rest volumes, plastic strain or None, remesh report)."""
    from idp.energies.elastic import _rest_matrices

    el = body.elastic
    Dm = np.linalg.inv(el.rest_frames_inverse)  # effective rest frames (base with any rest transform)
    vol = np.array(el.volumes)
    alpha = None
    if plasticity is not None and plasticity.model.plastic_strain is not None:
        alpha = np.array(plasticity.model.plastic_strain)
    report: dict = {}
    if what in ("bake", "bake_remesh"):
        Dm = _rest_matrices(x_body, elements)
        vol = np.abs(np.linalg.det(Dm)) / math.factorial(x_body.shape[1])
    if what in ("remesh", "bake_remesh"):
        from idp.mesh.remesh import mesher_available, remesh_volume
        from idp.mesh.transfer import transfer_cell_data, transfer_rest_frames

        if not mesher_available():  # if_unavailable = "skip" (an "error" stage was refused before running)
            log.warning("stage %s: the mesher is not installed; %s carries its mesh on", stage.name, body.name)
            report = {"skipped": 'mesher not installed (pip install "idp[remesh]")'}
        else:
            rm = stage.remesh
            res = remesh_volume(
                x_body, elements, quality=rm.quality, max_volume=rm.max_volume, refine_surface=rm.refine_surface
            )
            new_x, new_el = res.vertices, res.elements
            if what == "bake_remesh":
                Dm = _rest_matrices(new_x, new_el)
            else:
                Dm = transfer_rest_frames(x_body, elements, Dm, new_x, new_el)
            vol = np.abs(np.linalg.det(Dm)) / math.factorial(x_body.shape[1])
            if alpha is not None:
                alpha = transfer_cell_data(x_body, elements, new_x, new_el, {"alpha": alpha})["alpha"]
            report = {
                "elements_before": int(elements.shape[0]),
                "elements_after": int(new_el.shape[0]),
                "vertices_before": int(x_body.shape[0]),
                "vertices_after": int(new_x.shape[0]),
                "quality_before": res.quality_before.to_dict(),
                "quality_after": res.quality_after.to_dict(),
            }
            return VolumeMesh(new_x, new_el, source="remesh"), Dm, vol, alpha, report
    return VolumeMesh(x_body, elements, source="stage"), Dm, vol, alpha, report


def _write_end_states(
    built, result, stage: StageSpec, k: int, sdir: Path, states: dict[str, ObjectState], taking: list[str]
) -> dict[str, dict]:
    """Write every taking-part object's end state into ``sdir/state`` and point its ObjectState there."""
    from idp.stepper.conditions import Plasticity

    state_dir = sdir / "state"
    state_dir.mkdir(exist_ok=True)
    system = built.system
    x = result.x
    bodies = {b.name: b for b in system.bodies}
    plastic = {c.body.name: c for c in system.conditions if isinstance(c, Plasticity)}
    report: dict[str, dict] = {}
    for part in system.parts:
        name = part.name
        ids = part.vertex_ids
        xb = np.ascontiguousarray(x[ids])
        what = stage.after.get(name, "carry")
        rec: dict[str, Any] = {"kind": part.kind, "after": what}
        mesh_path = state_dir / f"{name}.vtu"
        rest_path = None
        mesh: VolumeMesh | SurfaceMesh
        if part.kind == "deformable":
            assert part.elements is not None
            if what != "carry" and not result.summary.get("all_certified", False):
                raise SceneError(
                    f"stages[{k}] ({stage.name}).after.{name} = {what!r}: the stage's last state is not certified"
                )
            mesh, Dm, vol, alpha, rm = _deformable_end_state(
                bodies[name], plastic.get(name), xb, part.elements - ids[0], what, stage
            )
            rest_path = state_dir / f"{name}.rest.npz"
            write_rest_state(rest_path, Dm, vol, alpha)
            if rm:
                rec["remesh"] = rm
            rec["elements"] = int(mesh.elements.shape[0])
        else:
            mesh = SurfaceMesh(xb, part.surface - ids[0], source="stage")
        write_shape(mesh_path, mesh)
        rec["vertices"] = int(mesh.vertices.shape[0])
        rec["mesh"] = str(mesh_path)
        if rest_path is not None:
            rec["rest_state"] = str(rest_path)
        states[name].mesh, states[name].rest_state = mesh_path, rest_path
        report[name] = rec
    missing = [n for n in taking if n not in report]
    assert not missing, missing
    return report


def _load_done(path: Path) -> dict | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("status") == "done" else None


def _write_json(path: Path, data: dict) -> None:
    """Atomically, with the stats' JSON conventions (numpy values, paths, ±inf as strings)."""
    from idp.output.stats import to_jsonable

    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(to_jsonable(data), indent=2, allow_nan=False))
    tmp.replace(path)


def run_stages(
    scene: Scene,
    out_dir: str | Path,
    *,
    progress: bool = True,
    resume: bool = False,
    stop_after: int | str | None = None,
    force_resume: bool = False,
) -> StagedResult:
    """Run every stage of ``scene`` into ``out_dir`` (``OUT/stages/NN_name/`` per stage, ``OUT/final/`` the last
    shapes, ``OUT/stages.json`` the per-stage figures). ``stop_after``: run only the stages up to this one, given
    by index (0 = the first, as in the stage folders ``NN_name``) or name (then a later ``resume=True`` call goes
    on from there)."""
    from idp.api import run_built
    from idp.scene.build import build_scene

    if not scene.stages:
        raise SceneError("run_stages: the scene has no `stages`")
    stop_index = _stage_index(scene, stop_after)
    out = make_output_dir(check_output_dir(out_dir))
    _check_mesher(scene)
    resolved = resolved_scene_dict(scene)
    if resume:  # the whole staged scene, also its stages already done (each stage run checks its own too)
        check_resume_scene(out, resolved, force=force_resume)
    (out / "scene.resolved.json").write_text(json.dumps(resolved, indent=2))
    (out / "scene.resolved.toml").write_text(dump_scene_toml(scene))
    states: dict[str, ObjectState] = {ob.name: ObjectState(ob, 0) for ob in scene.objects}
    result = StagedResult(out)
    t0 = time.perf_counter()
    last = len(scene.stages) - 1 if stop_index is None else stop_index
    for k, stage in enumerate(scene.stages[: last + 1]):
        sdir = _stage_dir(out, k, stage)
        for name in stage.remove:
            states.pop(name, None)
        for ob in stage.add:
            states[ob.name] = ObjectState(ob, k)
        for st in states.values():
            _persist(st, stage)
        taking = [n for n in states if stage.objects is None or n in stage.objects]
        done = _load_done(sdir / "stage.json") if resume else None
        if done is not None:  # finished by an earlier (interrupted) run: take its end states
            for name, rec in done["objects"].items():
                states[name].mesh = Path(rec["mesh"])
                states[name].rest_state = Path(rec["rest_state"]) if "rest_state" in rec else None
            result.stages.append(done["summary"])
            log.info("stage %d (%s) finished earlier: skipped", k, stage.name)
            continue
        for ob in stage.add:  # placed relative to a current shape: resolved now that the shapes are known
            if ob.name in stage.anchor:
                states[ob.name].spec = _anchored(scene, ob, stage.anchor[ob.name], states)
        objects = [_stage_object(states[n], stage, k) for n in taking]
        stage_scene = _stage_scene(scene, stage, k, objects, sdir)
        log.info("stage %d/%d: %s (%d steps, objects %s)", k + 1, len(scene.stages), stage.name, stage.steps, taking)
        try:
            built = build_scene(stage_scene)
        except IdpError as exc:  # bad input of this stage: said with the stage's name
            raise type(exc)(f"stages[{k}] ({stage.name}): {exc}") from exc
        run = run_built(stage_scene, built, sdir, progress=progress, resume=resume, force_resume=force_resume)
        objects_rec = _write_end_states(built, run, stage, k, sdir, states, taking)
        kill_point("stage")  # crash-safety tests only: end states written, the done marker not yet
        s = run.summary
        summary = {
            "stage": stage.name,
            "index": k,
            "steps": s.get("steps_run"),
            "last_step": s.get("last_step"),
            "stopped": s.get("stopped"),
            "wall_time": s.get("wall_time"),
            "newton_iterations": s.get("newton_iterations"),
            "nonconverged_steps": s.get("nonconverged_steps"),
            "steps_with_unmet_targets": s.get("steps_with_unmet_targets"),
            "all_certified": s.get("all_certified"),
            "min_distance": s.get("min_distance"),
            "num_vertices": built.meta.get("num_vertices"),
            "num_elements": built.meta.get("num_elements"),
            "objects": objects_rec,
        }
        _write_json(sdir / "stage.json", {"status": "done", "objects": objects_rec, "summary": summary})
        result.stages.append(summary)
    if last == len(scene.stages) - 1:
        final = out / "final"
        final.mkdir(exist_ok=True)
        for stale in final.glob("*.vtu"):  # objects removed since an earlier run of a shorter stage list
            if stale.stem not in states:
                stale.unlink()
        for name, st in states.items():
            if st.mesh is not None:
                target = final / f"{name}.vtu"
                target.write_bytes(st.mesh.read_bytes())
                result.final_shapes[name] = target
        if scene.output.png:
            _render_final(scene, states, result.final_shapes, final / "final.png")
    per = result.stages
    result.summary = {
        "stages_run": len(per),
        "stages": len(scene.stages),
        "steps_run": int(sum(int(p.get("steps") or 0) for p in per)),
        "stopped": "every stage done" if len(per) == len(scene.stages) else f"stopped after stage {len(per) - 1}",
        "wall_time": float(sum(float(p.get("wall_time") or 0.0) for p in per)),
        "newton_iterations": int(sum(int(p.get("newton_iterations") or 0) for p in per)),
        "nonconverged_steps": int(sum(int(p.get("nonconverged_steps") or 0) for p in per)),
        "all_certified": result.all_certified,
        "uncertified_frames": 0 if result.all_certified else None,
        "min_distance": min(
            (float(p["min_distance"]) for p in per if p.get("min_distance") is not None), default=math.inf
        ),
        "driver_time": time.perf_counter() - t0,
        "per_stage": per,
    }
    _write_json(out / "stages.json", result.summary)
    return result
