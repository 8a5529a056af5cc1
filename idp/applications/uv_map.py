"""UV-map improvement (paper §7.4, Fig. 18) as a thin driver over the shared stepper.

:func:`uv_scene` turns an OBJ with texture coordinates into an ordinary 2D scene — one ``uv = true`` object whose
nodes are the file's vt coordinates, elements its UV triangles and rest metric its 3D triangles, with the p-norm
symmetric Dirichlet energy and the paper's stop rule — so a UV run is also a reproducible scene file.
:func:`run_uv` checks the input layout (flipped triangles, overlapping charts), runs the scene with the same Newton
loop, CCD line search, certificate and writers as every scene, then writes the OBJ back with only its vt lines
changed and a report of the distortion before and after.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from idp.errors import IntersectingInputError, MeshError, OutputError
from idp.fs import check_output_dir, is_dir
from idp.scene.schema import Scene

#: The authors' UV set-up (manifest, minmax/): E 2e4, ν 0.4, density 1000, d̂ = 1e-3; p = 10 for min-max.
DEFAULT_P = 10.0
DEFAULT_DHAT = 1e-3
DEFAULT_STEPS = 200
DEFAULT_NEWTON_TOL = 1e-3


def uv_scene(
    obj: str | Path,
    *,
    p: float = DEFAULT_P,
    steps: int = DEFAULT_STEPS,
    dhat: float = DEFAULT_DHAT,
    youngs_modulus: float = 2e4,
    newton_tol: float = DEFAULT_NEWTON_TOL,
    preserve_overlaps: bool = False,
    name: str | None = None,
) -> Scene:
    """A validated UV-improvement scene for ``obj`` (a path, or ``data:minmax/withUV/camelHead28K.obj``)."""
    from idp.scene.load import scene_from_dict

    doc: dict[str, Any] = {
        "name": name or f"uv-{Path(str(obj)).stem}",
        "dim": 2,
        "time": {"steps": int(steps), "stop_after_single_iteration": True},
        "solver": {"newton_tol": float(newton_tol)},
        "contact": {"dhat": float(dhat), "preserve_input_intersections": bool(preserve_overlaps)},
        "output": {"obj": False, "vtu": False, "png": False, "distortion": True},
        "objects": [
            {
                "name": "uv",
                "mesh": str(obj),
                "uv": True,
                "material": {
                    "model": "symmetric_dirichlet",
                    "youngs_modulus": float(youngs_modulus),
                    "poisson_ratio": 0.4,
                    "density": 1000.0,
                    "power": float(p),
                },
            }
        ],
    }
    return scene_from_dict(doc)


def default_report_dir(out_obj: Path) -> Path:
    """``OUT.obj`` → ``OUT_uv/`` beside it: report, pictures, stats and checkpoint of the run."""
    return out_obj.with_name(out_obj.stem + "_uv")


def run_uv(
    scene: Scene,
    out_obj: str | Path,
    *,
    report_dir: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = True,
    resume: bool = False,
    force_resume: bool = False,
) -> tuple[Any, dict]:
    """Improve the UV layout of the scene's ``uv`` object; write ``out_obj`` and the report. Returns
    (RunResult, report dict). Nothing is written when the input is refused (flipped or overlapping layout,
    missing vt, degenerate 3D triangles, output = input without ``overwrite``)."""
    from idp.api import run_built
    from idp.mesh.uv_obj import uv_overlaps
    from idp.output.uv_report import write_uv_report
    from idp.scene.build import build_scene

    uv_objects = [ob for ob in scene.objects if ob.uv]
    if len(uv_objects) != 1 or len(scene.objects) != 1:
        raise MeshError("run_uv: the scene must hold exactly one object, with uv = true")
    out = Path(out_obj)
    if is_dir(out):
        raise OutputError(f"{out}: is a folder; the output of idp uv is an OBJ file")
    check_output_dir(out.parent)
    check_output_dir(report_dir if report_dir is not None else default_report_dir(out))
    src = Path(str(uv_objects[0].mesh))  # as given (may be data:...); the resolved path once built
    try:  # resolves data: paths, reads and checks the OBJ before anything is written
        built = build_scene(scene)
    except IntersectingInputError as exc:  # chart boundaries cross: say it in UV terms
        raise IntersectingInputError(
            f"{src}: the UV layout overlaps itself ({exc}). With `idp uv`, --preserve-overlaps keeps the overlaps "
            "(no new one is ever added)"
        ) from exc
    uvo = next(iter(built.uv_objects.values())) if built.uv_objects else None
    assert uvo is not None
    src = Path(uvo.mesh.source)
    if out.resolve() == src.resolve() and not overwrite:
        raise MeshError(f"{out}: is the input file; choose another output or pass overwrite")
    before = uvo.mesh.uv.copy()
    overlaps = uv_overlaps(before, uvo.mesh.faces_uv, max_pairs=20)
    if overlaps.size and not scene.contact.preserve_input_intersections:
        pairs = ", ".join(f"({a}, {b})" for a, b in overlaps[:5].tolist())
        raise IntersectingInputError(
            f"{src}: the UV layout overlaps itself (triangle pairs {pairs}{', ...' if len(overlaps) > 5 else ''}; "
            "0-based face order): the map is not injective. Fix the layout, or keep the overlaps with "
            "--preserve-overlaps (no new overlap is ever added)"
        )
    rep_dir = Path(report_dir) if report_dir is not None else default_report_dir(out)
    result = run_built(scene, built, rep_dir, progress=progress, resume=resume, force_resume=force_resume)
    after = result.x[: before.shape[0]]
    from idp.mesh.uv_obj import write_uv_obj

    write_uv_obj(src, out, after, overwrite=overwrite)
    summary = result.summary
    extra = {
        "input": str(src),
        "output": str(out),
        "p": uv_objects[0].material.power if uv_objects[0].material is not None else 1.0,
        "steps": summary["steps_run"],
        "stopped": summary["stopped"],
        "newton_iterations": summary["newton_iterations"],
        "wall_time_s": summary["wall_time"],
        "all_certified": summary["all_certified"],
        "metric_scale": uvo.metric_scale,
        "mirrored_input": uvo.mirrored,
        "overlaps_preserved": len(overlaps),
    }
    report = write_uv_report(
        rep_dir,
        mesh=uvo.mesh,
        Dm=uvo.rest_frames,
        areas=uvo.areas,
        uv_before=before,
        uv_after=after,
        extra=extra,
        title=src.name,
    )
    return result, report
