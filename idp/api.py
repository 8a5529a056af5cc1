"""Python API: the same as a scene file, from code.

import idp
scene = idp.load_scene("scene.toml")          # or build idp.Scene(...) directly
result = idp.simulate(scene, "out", steps=10)
print(result.summary["fill_fraction"], result.summary["all_certified"])
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from idp.errors import SceneError
from idp.fs import check_output_dir, make_output_dir
from idp.kernel_cache import announcing
from idp.scene.build import BuiltScene, build_scene
from idp.scene.load import dump_scene_toml, load_scene, resolved_scene_dict
from idp.scene.resume_check import check_resume_scene
from idp.scene.schema import Scene
from idp.solver.linear import make_linear_solver
from idp.stepper.run import RunResult, run_simulation

log = logging.getLogger("idp")


def simulate(
    scene: Scene | str | Path,
    out_dir: str | Path | None = None,
    *,
    steps: int | None = None,
    progress: bool = True,
    resume: bool = False,
    force_resume: bool = False,
    check_every_iterate: bool | None = None,
    targets: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray] | None] | None = None,
    stop_after: int | str | None = None,
) -> RunResult:
    """Build the scene, run its artificial time steps, write frames/stats/picture, return the result.

    ``targets(step, x)``: Dirichlet targets streamed from code (paper §4.5), called before each step with the
    current positions (n, d) of the whole scene; it returns (global vertex ids, (k, d) targets) or None.
    They are resolved like a scene's handles (feasible move, adaptive penalty, hold once met).

    ``resume``: continue the interrupted run in ``out_dir`` from its checkpoint; refused when the scene differs
    from the one it was started with (other than ``time.steps`` / ``output.dir``) unless ``force_resume``.

    ``stop_after``: in a staged scene, the last stage to run (its name or index); a later ``resume=True`` call
    goes on from there."""
    with announcing(progress):  # a first run says it is compiling kernels (numba), not silently waits
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        out = Path(out_dir) if out_dir is not None else Path(scene.output.dir)
        check_output_dir(out)  # a file where the folder should be: said now, not after building the scene
        if scene.repair is not None:  # an animation repair: frames in the input's own form, and its report
            from idp.applications.repair import run_repair

            if targets is not None or check_every_iterate:
                raise SceneError("simulate: `targets` and `check_every_iterate` are not available for a repair scene")
            return run_repair(scene, out, progress=progress, resume=resume, steps=steps, force_resume=force_resume)
        if scene.stages:  # a multi-stage modeling scene: one run per stage (idp.applications.modeling)
            from idp.applications.modeling import run_stages

            if targets is not None or check_every_iterate or steps is not None:
                raise SceneError(
                    "simulate: `targets`, `check_every_iterate` and `steps` are per stage in a staged scene"
                )
            return run_stages(  # type: ignore[return-value]
                scene, out, progress=progress, resume=resume, force_resume=force_resume, stop_after=stop_after
            )
        if stop_after is not None:
            raise SceneError("simulate: `stop_after` names a stage, and this scene has no `stages`")
        # build first: bad input (a mesh, a selection, intersecting surfaces) fails before anything is written
        built = build_scene(
            scene, check_every_iterate=check_every_iterate, steps=steps, with_handles=targets is not None
        )
        if targets is not None:
            from idp.stepper.handles import HandleSet

            next(c for c in built.system.conditions if isinstance(c, HandleSet)).stream = targets
        return run_built(scene, built, out, progress=progress, resume=resume, force_resume=force_resume)


def run_built(
    scene: Scene,
    built: BuiltScene,
    out: Path,
    *,
    progress: bool = True,
    resume: bool = False,
    force_resume: bool = False,
    writer=None,
) -> RunResult:
    """Run a built scene into ``out`` (scene files, frames, stats, checkpoint): the one path every driver takes.
    ``writer``: the frame writer when not the default OBJ/VTU/PVD one (animation repair's sequence writer).
    A resume is refused when ``scene`` is not the one the run was started with (unless ``force_resume``)."""
    make_output_dir(out)
    resolved = resolved_scene_dict(scene)
    if resume:
        check_resume_scene(out, resolved, force=force_resume)
    (out / "scene.resolved.json").write_text(json.dumps(resolved, indent=2))
    (out / "scene.resolved.toml").write_text(dump_scene_toml(scene))
    built.run.progress = progress
    built.run.resume = resume
    dofs_per_node = scene.dim
    linear = make_linear_solver(scene.solver.linear_solver, dofs_per_node=dofs_per_node)
    meta = {
        "scene": scene.name,
        "resolved_scene": resolved,
        **built.meta,
        "linear_solver": linear.name,
        "newton_tol": built.newton.tol,
        "h": scene.time.h,
    }
    log.info(
        "dhat = %.6g (%s), %d vertices, %d elements",
        built.dhat,
        scene.contact.dhat_mode,
        built.meta["num_vertices"],
        built.meta["num_elements"],
    )
    return run_simulation(built.system, built.newton, linear, built.certifier, out, built.run, meta, writer=writer)
