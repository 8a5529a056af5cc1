"""Globally injective normal flow (paper §7.2) as a thin driver over the shared stepper.

:func:`flow_scene` turns a surface file and the flow's parameters into an ordinary scene (one shell object
with no elastic energy, as in the authors' set-up, and a ``[flow]`` section), so a flow is also runnable and
reproducible as a scene file; :func:`run_flow` runs it with :func:`idp.api.simulate` — the same Newton loop,
CCD line search, certificate and writers as every other scene.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from idp.scene.schema import Scene

DEFAULT_DHAT = 1e-3  # the authors' absolute d̂ for every flow (manifest, flow/)


def flow_scene(
    mesh: str | Path,
    *,
    beta: float,
    gamma: float = 0.5,
    steps: int = 10,
    dhat: float = DEFAULT_DHAT,
    name: str | None = None,
    laplacian: str = "area",
    normals: str = "mass",
    recompute: str = "auto",
    fix_boundary: bool = True,
    preserve_input_intersections: bool = False,
    newton_tol: float | None = None,
    output_dir: str | Path | None = None,
) -> Scene:
    """A validated normal-flow scene for the triangle surface ``mesh`` (a file path, or ``data:flow/cat.obj``).

    ``beta`` is the per-step push (time.h = 1), ``gamma`` the smoothing; ``newton_tol`` (RMS of the Newton step
    per vertex) defaults to the flow scenes' ``FLOW_TOL_FRACTION`` · |β| (set by the scene schema)."""
    doc: dict[str, Any] = {
        "name": name or Path(str(mesh)).stem,
        "dim": 3,
        "time": {"h": 1.0, "steps": int(steps)},
        "solver": {} if newton_tol is None else {"newton_tol": float(newton_tol)},
        "contact": {"dhat": float(dhat), "preserve_input_intersections": bool(preserve_input_intersections)},
        "flow": {
            "beta": float(beta),
            "gamma": float(gamma),
            "laplacian": laplacian,
            "normals": normals,
            "recompute": recompute,
            "fix_boundary": bool(fix_boundary),
        },
        "objects": [
            {
                "name": "surface",
                "kind": "shell",
                "mesh": str(mesh),
                "shell": {"youngs_modulus": 0.0, "bending": 0.0, "density": 1.0, "thickness": 1.0},
            }
        ],
    }
    if output_dir is not None:
        doc["output"] = {"dir": str(output_dir)}
    from idp.scene.load import scene_from_dict

    return scene_from_dict(doc)


def run_flow(
    scene: Scene, out_dir: str | Path, *, progress: bool = True, resume: bool = False, force_resume: bool = False
):
    """Run a flow scene (from :func:`flow_scene` or a scene file with ``[flow]``); return the RunResult."""
    if scene.flow is None:
        from idp.errors import SceneError

        raise SceneError("flow: the scene has no [flow] section")
    from idp.api import simulate

    return simulate(scene, out_dir, progress=progress, resume=resume, force_resume=force_resume)
