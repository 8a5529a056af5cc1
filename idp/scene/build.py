"""Turn a validated :class:`~idp.scene.schema.Scene` into a ready-to-step System (mesh → energies → contact)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from idp.contact.certificate import Certifier
from idp.contact.model import ContactModel
from idp.energies.elastic import ElasticEnergy, lame_parameters
from idp.energies.gravity import GravityPotential
from idp.energies.inertia import lumped_masses
from idp.energies.pnorm import PNormEnergy
from idp.errors import IntersectingInputError, MeshError, SceneError
from idp.kernel_cache import prepare as prepare_kernels
from idp.mesh import generate as gen
from idp.mesh.io import read_mesh
from idp.mesh.placement import place, select_in_box
from idp.mesh.surface import boundary_edges, boundary_faces, enclosed_volume, surface_topology
from idp.mesh.types import SurfaceMesh, VolumeMesh
from idp.output.parts import Part
from idp.scene.build_handles import motion_from_spec, selection_from_spec
from idp.solver.newton import NewtonSettings, contact_lookahead_reach, line_search_extrapolation
from idp.stepper.dirichlet import DirichletTargets
from idp.stepper.distortion import DistortionMonitor
from idp.stepper.handles import Handle, HandleSet, check_static_overlaps
from idp.stepper.run import RunSettings
from idp.stepper.system import Body, RestShapeSchedule, System, WeightedTerm

log = logging.getLogger("idp")

GENERATORS: dict[str, Callable[..., VolumeMesh | SurfaceMesh]] = {
    "ball": gen.tet_ball,
    "ellipsoid": gen.tet_ellipsoid,
    "tet_box": gen.tet_box,
    "box_surface": gen.box_surface,
    "ellipsoid_surface": gen.ellipsoid_surface,
    "cylinder_surface": gen.cylinder_surface,
    "hourglass_surface": gen.hourglass_surface,
    "disk": gen.tri_disk,
    "rectangle": gen.tri_rectangle,
    "circle_polygon": gen.polygon_circle,
    "box_polygon": gen.polygon_box,
}


#: preserve mode: input surface pairs closer than this fraction of the bounding-box diagonal count as touching
#: (part of a crossing; the barrier cannot be evaluated there) and are left out of the barrier and CCD
TOUCHING_FRACTION = 1e-9


@dataclass
class BuiltScene:
    system: System
    certifier: Certifier
    newton: NewtonSettings
    run: RunSettings
    dhat: float
    input_intersections: int
    meta: dict
    uv_objects: dict[str, UVObject] | None = None


def _sequence_frame(obj, usd_prim: str | None) -> SurfaceMesh:
    """Frame ``obj.frame`` of the animation sequence ``obj.mesh`` as a triangle surface."""
    from idp.mesh.sequence import open_sequence

    seq = open_sequence(obj.mesh, usd_prim=usd_prim)
    if obj.frame >= seq.num_frames:
        raise MeshError(f"{obj.mesh}: frame {obj.frame} asked for, the sequence has {seq.num_frames} frames")
    return SurfaceMesh(seq.frame(obj.frame), seq.faces, source=seq.describe(obj.frame))


def _load_object_mesh(obj, dim: int, usd_prim: str | None = None) -> VolumeMesh | SurfaceMesh:
    want = "volume" if obj.kind == "deformable" else "surface"
    if obj.kind == "shell":
        from idp.mesh.surface_checks import check_shell_surface

        mesh: VolumeMesh | SurfaceMesh
        if obj.frame is not None:
            mesh = _sequence_frame(obj, usd_prim)
        elif obj.generate:
            mesh = GENERATORS[obj.generate.shape](**obj.generate.params())
        else:
            mesh = read_mesh(obj.mesh, kind=want)
        if not isinstance(mesh, SurfaceMesh) or mesh.faces.shape[1] != 3:
            raise MeshError(f"{mesh.source}: object {obj.name!r} is a shell but the mesh is not a triangle surface")
        check_shell_surface(mesh.vertices, mesh.faces, mesh.source)
        return mesh
    if obj.generate is not None:
        mesh = GENERATORS[obj.generate.shape](**obj.generate.params())
    elif obj.frame is not None:
        mesh = _sequence_frame(obj, None)
    elif obj.tetrahedralize is not None:
        mesh = _tetrahedralized(obj)
    else:
        try:
            mesh = read_mesh(obj.mesh, kind=want)
        except MeshError as exc:
            if want == "volume" and dim == 3 and _is_triangle_surface(obj.mesh):
                raise MeshError(
                    f"{exc}; a deformable body can be filled from a closed surface with `tetrahedralize = {{}}` "
                    '(needs pip install "idp[remesh]")'
                ) from exc
            raise
    if want == "volume" and not isinstance(mesh, VolumeMesh):
        raise MeshError(f"{mesh.source}: object {obj.name!r} is deformable but the mesh has no volume elements")
    if want == "surface" and not isinstance(mesh, SurfaceMesh):
        # an obstacle given as a volume mesh (file or generated solid): its boundary surface, interior dropped
        faces = boundary_faces(mesh.elements)
        used, inverse = np.unique(faces, return_inverse=True)
        mesh = SurfaceMesh(mesh.vertices[used], inverse.reshape(faces.shape), source=mesh.source)
    if mesh.vertices.shape[1] != dim:
        raise MeshError(f"{mesh.source}: object {obj.name!r} is {mesh.vertices.shape[1]}D but the scene is {dim}D")
    return mesh


def _is_triangle_surface(path) -> bool:
    try:
        m = read_mesh(path, kind="surface")
    except MeshError:
        return False
    return isinstance(m, SurfaceMesh) and m.faces.shape[1] == 3 and m.vertices.shape[1] == 3


def _tetrahedralized(obj) -> VolumeMesh:
    """`tetrahedralize`: the object's closed surface file filled with tets (TetGen, the optional mesher)."""
    from idp.errors import MesherUnavailableError
    from idp.mesh.remesh import tetrahedralize_surface

    surf = read_mesh(obj.mesh, kind="surface")
    if not isinstance(surf, SurfaceMesh) or surf.faces.shape[1] != 3 or surf.vertices.shape[1] != 3:
        raise MeshError(f"{surf.source}: `tetrahedralize` needs a 3D triangle surface")
    spec = obj.tetrahedralize
    try:
        v, t = tetrahedralize_surface(
            surf.vertices, surf.faces, quality=spec.quality, max_volume=spec.max_volume, source=surf.source
        )
    except MesherUnavailableError as exc:
        raise MesherUnavailableError(
            f"tetrahedralize: filling {surf.source} with tets needs the optional mesher; "
            'install it with pip install "idp[remesh]"'
        ) from exc
    log.info(
        "%s: %d surface vertices filled with %d tets (%d vertices)",
        surf.source,
        surf.vertices.shape[0],
        t.shape[0],
        v.shape[0],
    )
    return VolumeMesh(v, t, source=surf.source)


@dataclass
class UVObject:
    """A UV map read for simulation (paper §7.4): its file, rest metric from 3D and whether it was mirrored."""

    mesh: Any  # idp.mesh.uv_obj.UVMesh
    rest_frames: np.ndarray  # (m, 2, 2) of the 3D triangles, in the simulation's triangle order
    areas: np.ndarray  # (m,) 3D triangle areas
    mirrored: bool  # every UV triangle was clockwise: vertex order swapped for the simulation
    metric_scale: float  # the 3D lengths' factor that makes the total 3D area equal the UV area


def _load_uv_object(obj, i: int) -> tuple[Any, UVObject]:
    """The UV layout of an OBJ as a 2D triangle mesh (nodes = vt) and the rest metric of its 3D triangles."""
    from idp.mesh.uv_obj import orient_uv_mesh, read_uv_obj, uv_rest_frames, uv_signed_areas

    try:
        uvm, mirrored = orient_uv_mesh(read_uv_obj(obj.mesh))
        Dm, areas = uv_rest_frames(uvm.positions, uvm.faces_xyz, face_lines=uvm.face_lines, source=uvm.source)
    except MeshError as exc:
        raise MeshError(f"objects[{i}] ({obj.name}): {exc}") from exc
    # distortion is of shape, not of the layout's overall scale (UV tools normalise charts to the unit square):
    # the 3D metric is scaled uniformly so that the total 3D area equals the total UV area
    scale = float(np.sqrt(np.abs(uv_signed_areas(uvm.uv, uvm.faces_uv)).sum() / areas.sum()))
    Dm, areas = Dm * scale, areas * scale**2
    if mirrored:
        log.warning("%s: every UV triangle is clockwise; simulating the mirrored layout", uvm.source)
    mesh = VolumeMesh(np.ascontiguousarray(uvm.uv), np.ascontiguousarray(uvm.faces_uv), source=uvm.source)
    return mesh, UVObject(uvm, Dm, areas, mirrored, scale)


def _apply_rest_state(obj, elastic) -> dict[str, np.ndarray]:
    """Set a body's rest frames from ``obj.rest_state`` (an .npz an earlier stage wrote: ``rest_frames``
    (m,d,d), ``volumes`` (m,), optionally ``plastic_strain`` (m,)); MeshError naming the file when it does not
    fit the mesh."""
    from idp.stepper.stage_state import read_rest_state

    st = read_rest_state(obj.rest_state, elastic.elements.shape[0], elastic.dim)
    try:
        elastic.set_base_rest_frames(st["rest_frames"], st["volumes"])
    except ValueError as exc:
        raise MeshError(f"objects {obj.name!r}: rest_state {obj.rest_state}: {exc}") from None
    return st


def _place(obj, vertices: np.ndarray, dim: int) -> np.ndarray:
    """The object's own placement (scale, rotate about the origin, translate), then its instance transform."""
    rots = [r.degrees if dim == 2 else (tuple(r.axis), r.degrees) for r in (obj.rotate or [])]
    placed = place(vertices, scale=obj.scale, rotations=rots, translation=obj.translate)
    if getattr(obj, "instance_transform", None) is not None:
        matrix, shift = obj.instance_transform.arrays()
        placed = placed @ matrix.T + shift
    return placed


def _fixed_vertices(obj, i: int, verts: np.ndarray) -> np.ndarray:
    """(n,) bool: the object's vertices that its ``fixed`` selectors pin."""
    n = verts.shape[0]
    pinned = np.zeros(n, dtype=bool)
    for j, sel in enumerate(obj.fixed or []):
        if sel.indices is not None:
            idx = np.asarray(sel.indices, dtype=np.int64)
            if idx.size and idx.max() >= n:
                raise SceneError(
                    f"objects[{i}].fixed[{j}].indices: index {int(idx.max())} out of range (mesh has {n} vertices)"
                )
            pinned[idx] = True
        if sel.box is not None:
            rel = (verts.min(axis=0), verts.max(axis=0)) if sel.relative else None
            sel_idx = select_in_box(
                verts, np.asarray(sel.box[0], float), np.asarray(sel.box[1], float), relative_to=rel
            )
            if sel_idx.size == 0:
                log.warning("objects[%d].fixed[%d]: the box selects no vertex", i, j)
            pinned[sel_idx] = True
    return pinned


def _element_densities(obj, i: int, mesh, verts: np.ndarray) -> np.ndarray:
    """(m,) density per element: the material's, then each ``density_regions`` entry over the elements whose
    vertices its selection all picks (on the placed shape)."""
    from idp.scene.build_handles import selection_from_spec

    elements = mesh.elements
    rho = np.full(elements.shape[0], float(obj.material.density))
    for j, reg in enumerate(obj.density_regions):
        key = f"objects[{i}] ({obj.name}).density_regions[{j}]"
        try:
            chosen = selection_from_spec(reg.select, getattr(mesh, "point_groups", None)).select(verts)
        except IndexError as exc:
            raise SceneError(f"{key}.select.indices: {exc}") from exc
        except SceneError as exc:
            raise SceneError(f"{key}: {exc}") from exc
        picked = np.zeros(verts.shape[0], dtype=bool)
        picked[chosen] = True
        inside = picked[elements].all(axis=1)
        if not inside.any():
            raise SceneError(f"{key}: the selection holds no whole element ({chosen.size} vertices picked)")
        rho[inside] = float(reg.density)
    return rho


def _vector(v, dim: int) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return np.full(dim, float(a)) if a.ndim == 0 else a


def build_scene(
    scene, *, check_every_iterate: bool | None = None, steps: int | None = None, with_handles: bool = False
) -> BuiltScene:
    """Load/generate and place every object, pick pinned DOFs, set up energies, contact and the certificate.

    Input that intersects is refused (IntersectingInputError naming the pairs) unless
    ``contact.preserve_input_intersections`` is set, in which case those pairs are excluded from the
    barrier, CCD and certificate, and every other pair stays guarded (paper §5.5).

    ``with_handles``: set up the Dirichlet machinery even when the scene has no handles (for targets streamed
    from code, :attr:`idp.stepper.handles.HandleSet.stream`)."""
    dim = scene.dim
    deformables: list[tuple[int, Any, Any, np.ndarray]] = []  # VolumeMesh, or SurfaceMesh for shells
    obstacles: list[tuple[int, Any, SurfaceMesh, np.ndarray]] = []
    uv_objects: dict[str, UVObject] = {}
    for i, obj in enumerate(scene.objects):
        if obj.uv:
            mesh, uv_objects[obj.name] = _load_uv_object(obj, i)
        else:
            try:
                mesh = _load_object_mesh(obj, dim, scene.repair.usd_prim if scene.repair is not None else None)
            except MeshError as exc:
                raise MeshError(f"objects[{i}] ({obj.name}): {exc}") from exc
        verts = _place(obj, mesh.vertices, dim)
        if obj.kind in ("deformable", "shell"):
            deformables.append((i, obj, mesh, verts))
        else:
            assert isinstance(mesh, SurfaceMesh)
            obstacles.append((i, obj, mesh, verts))

    # global numbering: deformables first, then obstacles (static)
    chunks, parts, bodies = [], [], []
    fixed = []
    surfaces = []
    offset = 0
    shells: list[tuple[Any, np.ndarray, np.ndarray]] = []  # (object, global ids, global triangles)
    object_ids: dict[str, np.ndarray] = {}
    densities: dict[str, np.ndarray] = {}  # per-element densities of bodies with density regions
    for i, obj, mesh, verts in deformables:
        n = verts.shape[0]
        ids = np.arange(offset, offset + n)
        object_ids[obj.name] = ids
        if obj.kind == "shell":
            faces = mesh.faces + offset
            chunks.append(verts)
            parts.append(Part(obj.name, "shell", ids, None, faces))
            surfaces.append(faces)
            shells.append((obj, ids, faces))
            pinned = _fixed_vertices(obj, i, verts)
            fix_boundary = obj.fix_boundary
            if fix_boundary is None:  # flows pin open outlines by default (the fonts); other shells do not
                fix_boundary = scene.flow.fix_boundary if scene.flow is not None else False
            if fix_boundary:
                pinned[np.unique(boundary_edges(mesh.faces))] = True
            fixed.append(pinned)
            offset += n
            continue
        elements = mesh.elements + offset
        surface = boundary_faces(mesh.elements) + offset
        mat = obj.material
        E, nu = mat.youngs_modulus, mat.poisson_ratio
        lame_parameters(E, nu)  # validates the material before any heavy work
        chunks.append(verts)
        parts.append(Part(obj.name, "deformable", ids, elements, surface))
        surfaces.append(surface)
        rest = obj.rest_shape
        sched = RestShapeSchedule(
            _vector(rest.scale if rest else 1.0, dim),
            float(rest.growth_rate) if rest else 0.0,
            int(rest.growth_steps) if rest else 0,
        )
        bodies.append((obj, ids, elements, sched))
        if obj.density_regions:
            densities[obj.name] = _element_densities(obj, i, mesh, verts)
        fixed.append(_fixed_vertices(obj, i, verts))
        offset += n
    num_dynamic = offset
    cage_volume = 0.0
    dynamic_sample = _sample(chunks) if num_dynamic else None  # cage test points (the deformables' vertices)
    # kinematic (moving) obstacles first, then the static ones
    obstacles.sort(key=lambda item: item[1].motion is None)
    kinematic = []
    for i, obj, mesh, verts in obstacles:
        topo = surface_topology(mesh.faces, verts.shape[0])
        if not topo.is_closed:
            raise MeshError(
                f"objects[{i}] ({obj.name}): obstacle surface {mesh.source} is not closed: "
                f"{topo.num_boundary_edges} boundary edge(s), {topo.num_nonmanifold_edges} non-manifold edge(s)"
            )
        n = verts.shape[0]
        ids = np.arange(offset, offset + n)
        surface = mesh.faces + offset
        chunks.append(verts)
        parts.append(Part(obj.name, "obstacle", ids, None, surface))
        surfaces.append(surface)
        fixed.append(np.ones(n, dtype=bool))  # kinematic ones too: moved as a whole (stepper/dirichlet.py)
        if obj.motion is not None:
            kinematic.append((i, obj, ids))
        elif _encloses(verts, mesh.faces, dynamic_sample):
            cage_volume += abs(enclosed_volume(verts, mesh.faces))  # a cage: its fill fraction is reported
        offset += n

    x = np.ascontiguousarray(np.vstack(chunks), dtype=float)
    N = x.shape[0]
    all_surface = np.vstack(surfaces).astype(np.int64)

    masses = np.zeros(N)
    energies = []
    rest_states: dict[str, dict[str, np.ndarray]] = {}
    for obj, ids, elements, sched in bodies:
        mat = obj.material
        args = (mat.model, x, elements, mat.youngs_modulus, mat.poisson_ratio)
        weight = getattr(mat, "weight", None)
        el = ElasticEnergy(*args, weight=weight) if mat.power == 1.0 else PNormEnergy(*args, weight, mat.power)
        if obj.name in uv_objects:  # rest metric of the 3D triangles, not of the UV layout
            uvo = uv_objects[obj.name]
            el.set_base_rest_frames(uvo.rest_frames, uvo.areas)
        if obj.rest_state is not None:  # rest frames (and plastic state) an earlier stage ended with
            rest_states[obj.name] = _apply_rest_state(obj, el)
        masses += lumped_masses(N, elements, el.volumes, densities.get(obj.name, mat.density))
        energies.append(Body(obj.name, ids, el, sched))
    shell_terms = _shell_terms(shells, x, masses)
    material_conditions = _material_conditions(scene, energies, parts, x, rest_states)
    pinned = np.concatenate(fixed)
    free_mask = np.repeat(~pinned, dim)
    if not free_mask.any():
        raise SceneError("every vertex is fixed: nothing to deform")
    # the input is read and checked: compile what the cache lacks now (both cores, with a progress bar when
    # announcing) rather than kernel by kernel on first call
    prepare_kernels(scene)

    # contact distance
    diag = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
    c = scene.contact
    dhat = c.dhat * diag if c.dhat_mode == "relative" else c.dhat

    preserved: set = set()
    n_pairs = n_touching = 0
    if c.enabled:
        preserved, n_pairs = _input_intersections(x, all_surface, parts, dim, c.preserve_input_intersections)
        if not c.preserve_input_intersections:
            _refuse_nested(x, parts)
        contact = ContactModel(
            x,
            all_surface,
            num_dynamic,
            dhat,
            ccd=c.ccd,
            broad_phase=c.broad_phase,
            kappa=None if c.kappa == "auto" else float(c.kappa),
            adaptive_kappa=c.adaptive_kappa,
            barrier=c.barrier,
            kappa_init=c.kappa_init,
        )
        if c.preserve_input_intersections:
            touching = contact.exclude_touching(x, TOUCHING_FRACTION * diag)
            if touching:
                log.warning(
                    "preserving %d surface pair(s) that touch exactly inside the input's crossings "
                    "(left out of the barrier and CCD; the crossings they may turn into are preserved too)",
                    len(touching),
                )
                preserved |= _touching_crossings(touching, all_surface)
            n_touching = len(touching)
            if preserved:  # pairs around a kept crossing are squeezed by design: κ does not chase them
                contact.exempt_from_kappa(np.unique([v for key in preserved for side in key for v in side]))
        ev = contact.evaluate(x)
        if ev.num_active and contact.min_distance(ev) <= 0.0:
            raise IntersectingInputError(
                "surfaces touch (zero distance) in the start state; separate them by a small gap"
            )
    else:
        contact = None

    meta = {
        "dhat": dhat,
        "dhat_mode": c.dhat_mode,
        "bbox_diagonal": diag,
        "cage_volume": cage_volume or None,
        "num_vertices": N,
        "num_dynamic_vertices": num_dynamic,
        "num_elements": int(sum(b.elastic.elements.shape[0] for b in energies)),
        "num_shell_triangles": int(sum(f.shape[0] for _, _, f in shells)),
        "num_surface_primitives": int(all_surface.shape[0]),
        "num_free_dofs": int(free_mask.sum()),
        "input_intersecting_pairs": n_pairs,
        "input_touching_pairs_left_out": n_touching,
    }
    handles = _build_handles(scene, deformables, kinematic, object_ids, x, pinned, np.sqrt(scene.time.h))
    repair = _repair_frames(scene, shells, shell_terms, preserved) if scene.repair is not None else None
    prescribed_group = None  # vertices whose pairs among themselves are left out of contact (they follow the input)
    if repair is not None:
        with_handles = with_handles or repair.prescribed.size > 0
        meta["repair_frames"] = [repair.frames[0], repair.frames[-1]]
        meta["prescribed_vertices"] = int(repair.prescribed.size)
        assert scene.repair is not None
        if contact is not None and repair.prescribed.size and scene.repair.prescribed_contact == "follow_input":
            prescribed_group = np.zeros(N, dtype=bool)
            prescribed_group[repair.vertex_ids[repair.prescribed]] = True
            try:
                contact.leave_out_pairs_among(prescribed_group)
            except ValueError as exc:
                raise SceneError(f"repair.prescribed_contact = 'follow_input': {exc}; set it to 'guarded'") from None
        meta["prescribed_contact"] = scene.repair.prescribed_contact
    linear_terms: list = []
    if scene.gravity is not None and any(scene.gravity):
        linear_terms.append(GravityPotential(masses, np.asarray(scene.gravity, dtype=float)))
        meta["gravity"] = [float(v) for v in scene.gravity]
    flow = _normal_flow(scene, shells, x, shell_terms, linear_terms)
    system = System(
        dim,
        x,
        masses,
        free_mask,
        energies,
        parts,
        scene.time.h,
        contact,
        num_dynamic,
        meta,
        extra_terms=shell_terms,
        linear_terms=linear_terms,
    )
    system.conditions.extend(material_conditions)
    if scene.sticky is not None:
        _sticky(scene, parts, system)
    want_distortion = scene.output.distortion
    if want_distortion is None:
        want_distortion = bool(uv_objects) or any(b[0].material.power != 1.0 for b in bodies)
    if want_distortion and energies:
        part_index = {p.name: k for k, p in enumerate(parts)}
        system.conditions.append(DistortionMonitor(energies, [part_index[b.name] for b in energies]))
    if uv_objects:
        meta["uv_objects"] = {
            name: {"source": u.mesh.source, "mirrored": u.mirrored, "metric_scale": u.metric_scale}
            for name, u in uv_objects.items()
        }
    if repair is not None:
        system.conditions.append(repair)  # before the handle set: it streams the prescribed vertices' targets
    if flow is not None:
        system.conditions.append(flow)
    if handles or with_handles:
        dc = scene.dirichlet
        tol = dc.tolerance * dhat if dc.tolerance_mode == "dhat" else dc.tolerance
        bc = DirichletTargets(
            masses,
            dim,
            tolerance=tol,
            free_vertices=~pinned,
            kappa_initial=dc.kappa_initial,
            max_doublings=dc.max_doublings,
            detect_blocked=dc.detect_blocked,
            met_rule=dc.met_rule,
            met_progress=dc.met_progress,
        )
        system.step_constraint = bc
        fixed_deformable = pinned.copy()
        fixed_deformable[num_dynamic:] = False  # obstacle vertices are bound only by their own motion
        handle_set = HandleSet(handles, bc, float(np.sqrt(scene.time.h)), pinned=fixed_deformable)
        if repair is not None and repair.prescribed.size:
            handle_set.stream = repair.targets
        system.conditions.append(handle_set)
        meta["handles"] = [h.name for h in handles]
        meta["dirichlet_tolerance"] = tol
    guards_inversion = all(getattr(b.elastic, "guards_inversion", True) for b in energies)
    if not guards_inversion:
        log.warning("non-barrier elastic energy: inversion is not guarded; the certificate reports inverted elements")
    if not c.enabled:
        log.warning("contact is off: only locally injective; the certificate counts intersecting surface pairs")
    certifier = Certifier(
        x,
        all_surface,
        system.elements,
        distance_query=dhat,
        require_inversion_free=guards_inversion,
        require_intersection_free=c.enabled,
        preserved_pairs=preserved,
        shell_faces=np.vstack([f for _, _, f in shells]) if shells else None,
        prescribed_vertices=prescribed_group,
    )
    meta["guards_inversion"] = guards_inversion
    meta["guards_intersection"] = bool(c.enabled)
    s = scene.solver
    newton = NewtonSettings(
        extrapolate=line_search_extrapolation(s.line_search_extrapolation, system.terms),
        tol=s.newton_tol,
        norm=s.newton_norm,
        max_iterations=s.max_newton_iterations,
        inversion_eta=s.inversion_eta,
        check_every_iterate=s.check_every_iterate if check_every_iterate is None else check_every_iterate,
        max_seconds=s.max_step_seconds,
        max_memory=s.max_memory_bytes,
        contact_lookahead=contact_lookahead_reach(
            s.contact_lookahead, system.contact is not None and system.contact.compiled, bool(shells)
        ),
        island_steps=s.island_steps,
    )
    o, t = scene.output, scene.time
    if repair is not None:
        steps = min(steps, len(repair.frames) - 1) if steps else len(repair.frames) - 1
    run = RunSettings(
        steps=steps or t.steps,
        stop_when_stationary=t.stop_when_stationary,
        stop_after_single_iteration=t.stop_after_single_iteration,
        stationary_tol=t.stationary_tol,
        write_every=o.every,
        write_obj=o.obj,
        write_vtu=o.vtu,
        write_png=o.png,
        on_nonconvergence=s.on_nonconvergence,
        on_unmet_targets=scene.dirichlet.on_unmet,
        render_up=picture_up_axis(scene),
    )
    return BuiltScene(system, certifier, newton, run, dhat, n_pairs, meta, uv_objects)


def _sample(chunks: list[np.ndarray], count: int = 256) -> np.ndarray:
    """About ``count`` of the vertices in ``chunks``, evenly strided."""
    pts = np.vstack(chunks)
    return pts[:: max(1, pts.shape[0] // count)]


def _encloses(verts: np.ndarray, faces: np.ndarray, sample: np.ndarray | None) -> bool:
    """Whether a static obstacle is a cage: it holds every deformable body (a sample of their vertices has winding
    number 1 against it). A plate or a tool beside the bodies is not, and gets no fill fraction."""
    from idp.mesh.containment import winding_numbers

    if sample is None:
        return False
    return bool(np.all(winding_numbers(sample, verts, faces) > 0.5))


def _sticky(scene, parts, system) -> None:
    """`[sticky]`: a pair-spring term linked before steps (every step, or once as glue) between the matched bodies'
    surface vertices."""
    from idp.energies.pair_springs import PairSprings
    from idp.stepper.sticky import StickyContact

    st = scene.sticky
    chosen = set(st.matches([p.name for p in parts]))
    if system.contact is None or not system.contact.compiled or system.contact_pattern is None:
        raise SceneError("sticky: sticky contact needs contact on, in 3D, with the compiled barrier")
    verts, body, tris = [], [], []
    for k, p in enumerate(parts):
        if p.name in chosen and p.surface.size:
            v = np.unique(p.surface)
            verts.append(v)
            body.append(np.full(v.size, k, np.int64))
            tris.append(np.asarray(p.surface, np.int64).reshape(-1, 3))
    springs = PairSprings(system.dim, st.stiffness)
    system.pair_terms.append(springs)
    if len(verts) >= st.min_bodies:
        system.conditions.append(
            StickyContact(
                np.concatenate(verts),
                np.concatenate(body),
                st.distance,
                springs,
                mode=st.mode,
                triangles=np.concatenate(tris),
            )
        )
    system.meta["sticky"] = {
        "bodies": sorted(chosen),
        "distance": st.distance,
        "stiffness": st.stiffness,
        "mode": st.mode,
    }


def picture_up_axis(scene) -> str:
    """The axis drawn upwards in pictures: the scene's ``output.up``, or (auto) the axis most against gravity."""
    from idp.output.up_axis import up_axis

    return up_axis(scene.dim, scene.output.up, scene.gravity)


def _repair_frames(scene, shells, terms: list[WeightedTerm], preserved: set):
    """The §7.3 repair condition over the scene's one shell: every frame checked before anything is written."""
    from idp.mesh.sequence import open_sequence
    from idp.stepper.repair_frames import RepairFrames

    r = scene.repair
    seq = open_sequence(r.input, usd_prim=r.usd_prim)
    stop = seq.num_frames if r.stop is None else min(r.stop, seq.num_frames)
    if stop - r.start < 2:
        raise SceneError(
            f"repair: frames {r.start}:{stop} of {seq.path} ({seq.num_frames} frames) leave fewer than two to repair"
        )
    frames = list(range(r.start, stop))
    for k in frames:  # every frame checked (counts, faces, finite) before anything is written
        seq.frame(k)
    _obj, ids, faces = shells[0]
    first = seq.frame(frames[0])
    prescribed = np.zeros(first.shape[0], dtype=bool)
    for j, sel in enumerate(r.prescribed):
        if sel.indices is not None:
            idx = np.asarray(sel.indices, dtype=np.int64)
            if idx.max() >= first.shape[0]:
                raise SceneError(
                    f"repair.prescribed[{j}].indices: index {int(idx.max())} out of range ({first.shape[0]} vertices)"
                )
        else:
            rel = (first.min(axis=0), first.max(axis=0)) if sel.relative else None
            lo, hi = np.asarray(sel.box[0], float), np.asarray(sel.box[1], float)
            idx = select_in_box(first, lo, hi, relative_to=rel)
            if idx.size == 0:
                raise SceneError(f"repair.prescribed[{j}]: the box selects no vertex of frame {frames[0]}")
        prescribed[idx] = True
    names = {f"{obj.name}.membrane" for obj, _, _ in shells} | {f"{obj.name}.bending" for obj, _, _ in shells}
    rest_terms = [wt.term for wt in terms if wt.name in names]
    return RepairFrames(seq, frames, ids, faces, rest_terms, np.flatnonzero(prescribed), preserved)


def _shell_terms(shells, x: np.ndarray, masses: np.ndarray) -> list[WeightedTerm]:
    """Lumped shell masses (added into ``masses``) and each shell's membrane and bending terms (§4.4)."""
    from idp.energies.bending import BendingEnergy
    from idp.energies.membrane import MembraneEnergy
    from idp.mesh.differential import vertex_areas
    from idp.mesh.hinges import triangle_hinges

    terms: list[WeightedTerm] = []
    for obj, _ids, faces in shells:
        m = obj.shell
        masses += m.density * m.thickness * vertex_areas(x, faces)
        if m.youngs_modulus > 0:
            terms.append(
                WeightedTerm(
                    f"{obj.name}.membrane",
                    MembraneEnergy(x, faces, m.youngs_modulus, m.poisson_ratio, m.thickness),
                )
            )
            hinges = triangle_hinges(faces)
            if m.bending > 0 and len(hinges):
                terms.append(
                    WeightedTerm(
                        f"{obj.name}.bending",
                        BendingEnergy(
                            x, hinges, m.youngs_modulus, m.poisson_ratio, m.thickness, m.bending, m.bending_hessian
                        ),
                    )
                )
    return terms


def _normal_flow(scene, shells, x: np.ndarray, terms: list, linear_terms: list):
    """The §7.2 normal flow over every shell: its smoothing and push terms and its per-step condition."""
    if scene.flow is None:
        return None
    from idp.stepper.normal_flow import NormalFlow

    f = scene.flow
    faces = np.vstack([fc for _, _, fc in shells])
    mass_per_area = np.zeros(x.shape[0])
    closed = True
    for obj, ids, fc in shells:
        mass_per_area[ids] = obj.shell.density * obj.shell.thickness
        closed &= surface_topology(fc - ids[0], ids.size).is_closed
    flow = NormalFlow(
        x,
        faces,
        beta=f.beta,
        gamma=f.gamma,
        laplacian=f.laplacian,
        normals=f.normals,
        recompute_every_step=f.recompute_every_step,
        mass_per_area=mass_per_area,
        closed=closed,
    )
    if f.gamma > 0:
        terms.append(WeightedTerm("flow.smoothing", flow.smoothing))
    linear_terms.append(flow.force)
    return flow


def _material_conditions(
    scene, bodies: list[Body], parts: list[Part], x: np.ndarray, rest_states: dict[str, dict[str, np.ndarray]]
) -> list:
    """Rest-shape scale scripts (into each body's schedule), bakes, material stages and plasticity (§4.5)."""
    from idp.energies.plasticity import VonMisesPlasticity
    from idp.stepper.conditions import Bake, MaterialStages, Plasticity
    from idp.stepper.rest_shape import ScaleScript

    objs = [(i, ob) for i, ob in enumerate(scene.objects) if ob.kind == "deformable"]
    part_index = {p.name: k for k, p in enumerate(parts)}
    out: list = []
    for (i, ob), body in zip(objs, bodies, strict=True):
        el = body.elastic
        for j, rs in enumerate(ob.rest_scripts):
            if rs.type == "bake":
                out.append(Bake(body, rs.step))
                continue
            region = None
            if rs.region is not None:
                centroids = x[el.elements].mean(axis=1)
                picked = selection_from_spec(rs.region).select(centroids) if len(centroids) else np.zeros(0, int)
                if picked.size == 0:
                    raise SceneError(f"objects[{i}].rest_scripts[{j}].region: selects no element (by centroid)")
                region = np.zeros(el.elements.shape[0], dtype=bool)
                region[picked] = True
            rate = _vector(rs.rate, scene.dim)
            body.schedule.scripts.append(ScaleScript(rs.start, rs.end, rate, region))
        if ob.material_stages:
            mat = ob.material
            stages = [(st.youngs_modulus, st.poisson_ratio) for st in ob.material_stages]
            out.append(
                MaterialStages(
                    body, [st.start for st in ob.material_stages], stages, (mat.youngs_modulus, mat.poisson_ratio)
                )
            )
        if ob.plasticity is not None:
            # classical (uniaxial) von Mises σ_Y → radius of the Frobenius-norm yield surface: √(2/3) σ_Y
            model = VonMisesPlasticity(np.sqrt(2.0 / 3.0) * ob.plasticity.yield_stress, ob.plasticity.hardening)
            alpha = rest_states.get(ob.name, {}).get("plastic_strain")
            if alpha is not None:  # the accumulated plastic strain an earlier stage ended with (hardening)
                model.plastic_strain = np.array(alpha, dtype=float)
            out.append(Plasticity(body, model, part_index[ob.name]))
    return out


def _build_handles(scene, deformables, kinematic, object_ids, x, pinned, dt: float) -> list[Handle]:
    """Handles of the deformable objects and one whole-object handle per kinematic obstacle.

    Selections on the rest shape are made now, so an empty selection, an index out of range, a handle on
    fixed vertices, a targets file of the wrong size or two overlapping handles fail before anything runs."""
    from idp.mesh.selection import Selection

    handles: list[Handle] = []
    for i, obj, mesh, _ in deformables:
        ids = object_ids[obj.name]
        for j, hs in enumerate(obj.handles):
            key = f"objects[{i}].handles[{j}]"
            try:
                selection = selection_from_spec(hs.select, getattr(mesh, "point_groups", None))
            except SceneError as exc:
                raise SceneError(f"{key} ({hs.name}): {exc}") from exc
            h = Handle(
                f"{obj.name}.{hs.name}",
                ids,
                selection,
                motion_from_spec(hs.motion, key, dt),
                start=hs.start,
                end=hs.end,
                release=hs.release,
                select_on=hs.select_on,
                incremental=hs.motion.incremental,
            )
            try:
                if hs.select_on == "rest":
                    selected = h.select(x)
                    bad = selected[pinned[selected]]
                    if bad.size:
                        raise SceneError(
                            f"selects {bad.size} vertices that `fixed` pins (e.g. local vertex {int(bad[0] - ids[0])})"
                        )
                    h.motion.check_count(selected.size)
            except (SceneError, ValueError) as exc:
                msg = str(exc).replace(f"handle {h.name!r}: ", "")
                raise SceneError(f"{key} ({hs.name}): {msg}") from exc
            handles.append(h)
    for i, obj, ids in kinematic:
        km = obj.motion
        key = f"objects[{i}].motion"
        h = Handle(
            obj.name,
            ids,
            Selection(everything=True),
            motion_from_spec(km.motion, f"{key}.motion", dt),
            start=km.start,
            end=km.end,
            incremental=km.motion.incremental,
        )
        h.select(x)
        handles.append(h)
    check_static_overlaps(handles, scene.time.steps)
    return handles


def _touching_crossings(touching: list[tuple[list[int], list[int]]], faces: np.ndarray) -> set:
    """The edge–triangle crossings that exactly touching input pairs can turn into: an edge through an edge
    crosses a triangle of the other edge once they move; a vertex on a triangle lets its edges cross that triangle
    or its neighbours. Their spread beyond is guarded (every other pair keeps its barrier and CCD)."""
    if faces.shape[1] != 3:
        return set()
    from collections import defaultdict

    by_vertex: dict[int, list[int]] = defaultdict(list)
    for t, tri in enumerate(faces.tolist()):
        for v in tri:
            by_vertex[v].append(t)

    def tris_with(*vs: int) -> list[tuple[int, ...]]:
        common = set(by_vertex[vs[0]]).intersection(*(by_vertex[v] for v in vs[1:]))
        return [tuple(sorted(faces[t].tolist())) for t in common]

    keys: set = set()
    for a, b in touching:
        if len(a) == 2 and len(b) == 2:  # edge–edge
            keys |= {(tuple(sorted(a)), t) for t in tris_with(*b)}
            keys |= {(tuple(sorted(b)), t) for t in tris_with(*a)}
        else:  # a vertex vs a triangle (or an edge)
            v, other = (a[0], b) if len(a) == 1 else (b[0], a)
            near = {t for w in other for t in tris_with(w)}
            edges = {tuple(sorted((v, w))) for t in by_vertex[v] for w in faces[t].tolist() if w != v}
            keys |= {(e, t) for e in edges for t in near}
    return keys


def _refuse_nested(x: np.ndarray, parts: list[Part]) -> None:
    """IntersectingInputError when an object starts inside a deformable body's material (an instance, or an object
    added by a stage, placed into another body): surfaces that do not cross cannot show it, the winding number
    of one of its vertices can (a body held in a cavity, such as a dumpling filling, is outside the material)."""
    from idp.mesh.containment import winding_numbers

    if len(parts) < 2:
        return
    probes = np.array([int(p.vertex_ids[0]) if p.vertex_ids.size else -1 for p in parts])
    nested: list[tuple[str, str]] = []
    for a in parts:
        if a.kind != "deformable" or a.surface.size == 0:
            continue
        lo, hi = x[a.vertex_ids].min(axis=0), x[a.vertex_ids].max(axis=0)
        others = [
            k
            for k, b in enumerate(parts)
            if b is not a and probes[k] >= 0 and np.all((lo <= x[probes[k]]) & (x[probes[k]] <= hi))
        ]
        if not others:
            continue
        w = winding_numbers(x[probes[others]], x, a.surface)
        nested += [(parts[others[j]].name, a.name) for j in np.flatnonzero(w > 0.5)]
    if nested:
        shown = ", ".join(f"{b} inside {a}" for b, a in nested[:10])
        more = f" and {len(nested) - 10} more" if len(nested) > 10 else ""
        raise IntersectingInputError(
            f"the start state has {len(nested)} object(s) inside another body's material: {shown}{more}. "
            "Move or shrink them apart."
        )


def _describe_vertex(v: int, parts: list[Part]) -> str:
    for p in parts:
        if p.vertex_ids[0] <= v <= p.vertex_ids[-1]:
            return f"{p.name}:{v - p.vertex_ids[0]}"
    return str(v)


def _object_name(v: int, parts: list[Part]) -> str:
    for p in parts:
        if p.vertex_ids[0] <= v <= p.vertex_ids[-1]:
            return p.name
    return "?"


def _object_pairs(keys, parts: list[Part]) -> str:
    """Which objects intersect: ``ball_0 and ball_1 (56 pairs), ball_1 and ball_2 (56 pairs)`` (first 10)."""
    from collections import Counter

    counts: Counter = Counter()
    for a, b in keys:
        na, nb = _object_name(a[0], parts), _object_name(b[0], parts)
        counts[(na, nb) if (na, nb) <= (nb, na) else (nb, na)] += 1
    shown = [
        (f"{a} with itself" if a == b else f"{a} and {b}") + f" ({n} pair{'s' if n > 1 else ''})"
        for (a, b), n in sorted(counts.items())[:10]
    ]
    more = f" and {len(counts) - 10} more object pairs" if len(counts) > 10 else ""
    return ", ".join(shown) + more


def _input_intersections(x, surface, parts, dim, preserve: bool):
    """Find intersecting surface primitive pairs; refuse them, or return them to be preserved.

    Preserving (paper §5.5) needs no special treatment in the barrier or CCD: the barrier and CCD act
    on point-triangle and edge-edge pairs, which stay at positive distance around a crossing, so CCD
    keeps each crossing edge inside its triangle (the crossing can neither be undone nor spread to a
    new pair); the certificate then allows exactly the input's crossing pairs."""
    from idp.contact.intersections import intersecting_pair_keys

    keys = intersecting_pair_keys(x, surface)
    if not keys:
        return set(), 0
    if not preserve:
        kind = "triangle" if dim == 3 else "segment"
        shown = []
        for a, b in sorted(keys)[:5]:
            shown.append(
                "edge ("
                + ", ".join(_describe_vertex(v, parts) for v in a)
                + f") x {kind} ("
                + ", ".join(_describe_vertex(v, parts) for v in b)
                + ")"
            )
        raise IntersectingInputError(
            f"the start state has {len(keys)} intersecting surface primitive pair(s), between "
            + _object_pairs(keys, parts)
            + "; (object:vertex ids) e.g. "
            + "; ".join(shown)
            + ". Fix the input, or set contact.preserve_input_intersections = true to keep them"
            " (IDP then preserves, never removes, them)."
        )
    log.warning("preserving %d intersecting input primitive pair(s); every other pair stays guarded", len(keys))
    return keys, len(keys)
