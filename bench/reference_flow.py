"""Normal flows (paper §7.2, Figs. 12–14) run side by side with the authors' code, in turn, on this machine.

The prebuilt reference (``../shared/reference``) wraps only the §6 scripts in ``run.sh``; its library also holds
the authors' shell flow (``Drivers.FEMDiscreteShellBase``, ``Advance_One_Step_IE_Flow``). This script drives that
flow in a separate process with the set-up of the authors' ``12-14_normal_flow.py`` as the data manifest records
it (smoothIntensity s, magnitude, frames; dt = s, push magnitude/s², no elasticity or bending, d̂ = 1e-3
absolute, their default PNTol), and idp's committed scene of the same figure, alternating, and reports per run:
process wall (launch to exit: imports, set-up, OBJ per frame), the stepping wall, Newton iterations, peak RSS,
and the volume (closed) or area (open) ratio of the last frame to the first. No code of the reference is copied:
its library is called through its own Python API, only its printed and written results are read.

    .venv/bin/python bench/reference_flow.py -o bench/results/flow_ref [--only cat walnut11K] [--runs 2]

idp runs with OBJ frames only (the reference writes one OBJ per frame too) and ``--threads 2``; the reference
with ``OMP_NUM_THREADS=OPENBLAS_NUM_THREADS=2``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class FlowCase:
    """One figure: the authors' arguments (manifest ``flow/``) and idp's committed scene for it."""

    mesh: str
    smooth_intensity: float
    magnitude: float
    frames: int
    scene: str


CASES: dict[str, FlowCase] = {
    "cat": FlowCase("cat", 0.5, 5e-3, 10, "fig12_cat.toml"),
    "hand": FlowCase("hand", 0.5, 5e-3, 3, "fig12_hand.toml"),
    "walnut11K": FlowCase("walnut11K", 0.1, 5e-3, 8, "fig12_walnut11K.toml"),
    "bunny3K": FlowCase("bunny3K", 0.5, -5e-3, 50, "fig13_bunny3K.toml"),
    "feline": FlowCase("feline", 1.0, -5e-3, 50, "fig13_feline.toml"),
    "font_Tao": FlowCase("font_Tao", 0.5, 5e-3, 10, "fig14_font_Tao.toml"),
    "font_peng": FlowCase("font_peng", 0.5, 5e-3, 5, "fig14_font_peng.toml"),
    "font_delicious": FlowCase("font_delicious", 0.5, 5e-3, 12, "fig14_font_delicious.toml"),
    "font_seriously": FlowCase("font_seriously", 10.0, 5e-3, 25, "fig14_font_seriously.toml"),
}


def growth(first: Path, last: Path) -> tuple[str, float]:
    """("volume", V_last/V_first) for a closed surface, else ("area", A_last/A_first), from two triangle OBJs."""
    import meshio

    from idp.mesh.differential import face_area_normals
    from idp.mesh.surface import boundary_edges, enclosed_volume

    meshes = [meshio.read(p) for p in (first, last)]
    faces = np.asarray(meshes[0].cells_dict["triangle"], dtype=np.int64)
    points = [np.asarray(m.points, dtype=float) for m in meshes]
    if len(boundary_edges(faces)) == 0:
        return "volume", enclosed_volume(points[1], faces) / enclosed_volume(points[0], faces)
    area = [float(np.linalg.norm(face_area_normals(x, faces), axis=1).sum()) for x in points]
    return "area", area[1] / area[0]


# ---------------------------------------------------------------------------------------------------------------
# children


def reference_child(reference: Path, mesh: Path, case: FlowCase, work: Path, result: Path) -> None:
    """In the reference's process: the authors' flow set-up, then a JSON line of what it did."""
    scripts = work / "Projects" / "FEMShell" / "scripts"
    (work / "Projects" / "FEMShell" / "input").mkdir(parents=True)
    scripts.mkdir(parents=True)
    (work / "Projects" / "FEMShell" / "input" / f"{case.mesh}.obj").symlink_to(mesh)
    os.chdir(scripts)
    sys.path[:0] = [str(reference / "stubs"), str(reference / "Python"), str(reference / "lib")]
    sys.argv = ["12-14_normal_flow.py", case.mesh, str(case.smooth_intensity), str(case.magnitude), str(case.frames)]
    import Drivers  # type: ignore[import-not-found]
    from JGSL import Vector3d  # type: ignore[import-not-found]

    s = case.smooth_intensity
    sim = Drivers.FEMDiscreteShellBase("double", 3)
    sim.normalFlowMag = case.magnitude
    sim.frame_num = case.frames
    zero = Vector3d(0, 0, 0)
    sim.add_shell_3D(f"../input/{case.mesh}.obj", zero, zero, zero, 0)
    sim.dt, sim.frame_dt, sim.gravity = 1.0, 1.0, zero
    sim.flow = s > 0
    if sim.flow:
        sim.dt *= s
        sim.frame_dt *= s
        sim.normalFlowMag /= s * s
    sim.initialize(1, 0, 0, 1, 0)
    sim.bendingStiffMult = 0
    sim.withCollision = True
    sim.initialize_OIPC(1e-3, 0)
    # The prebuilt (modeling-branch) shell driver hands its library an outdated Dirichlet-motion storage type
    # when it steps moving Dirichlet conditions; a flow has none (open boundaries are fixed in place), so skip it.
    sim.MDBC_tmax = -1
    t0 = time.perf_counter()
    sim.run()
    stepping = time.perf_counter() - t0
    out = scripts / sim.output_folder
    record = {
        "stepping_s": stepping,
        "newton_iterations": int(sim.PNIterCount),
        "first": str(out / "shell0.obj"),
        "last": str(out / f"shell{case.frames}.obj"),
    }
    result.write_text(json.dumps(record))


def idp_child(scene_path: Path, out: Path, result: Path) -> None:
    """In idp's process: the committed scene with OBJ frames only."""
    from idp.cli import _set_threads

    _set_threads(2)
    from idp.api import simulate
    from idp.scene.load import load_scene

    scene = load_scene(scene_path)
    scene = scene.model_copy(update={"output": scene.output.model_copy(update={"vtu": False, "png": False})})
    simulate(scene, out, progress=False)
    stats = json.loads((out / "stats.json").read_text())
    steps = stats["steps"]
    record = {
        "stepping_s": float(stats["summary"]["wall_time"]),
        "newton_iterations": int(stats["summary"]["newton_iterations"]),
        "all_certified": bool(stats["summary"]["all_certified"]),
        "min_distance": stats["summary"].get("min_distance"),
        "first": str(sorted((out / "obj").glob("*.obj"))[0]),
        "last": str(sorted((out / "obj").glob("*.obj"))[-1]),
        "steps": len(steps),
    }
    result.write_text(json.dumps(record))


# ---------------------------------------------------------------------------------------------------------------
# parent


def run_once(which: str, name: str, case: FlowCase, reference: Path, data: Path, work: Path) -> dict:
    work.mkdir(parents=True)
    result = work / "result.json"
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", PYTHONDONTWRITEBYTECODE="1")
    blas = None
    if which == "reference":
        from idp.bench.reference_blas import choose_reference_blas

        env, blas = choose_reference_blas(env)  # its OpenBLAS on kernels for this CPU (idp/bench/reference_blas.py)
        cmd = [sys.executable, "-B", __file__, "--child-reference", name, str(reference), str(data), str(work)]
    else:
        scene = HERE.parent / "idp" / "scenes" / "paper" / case.scene
        cmd = [sys.executable, __file__, "--child-idp", name, str(scene), str(work / "out")]
    from idp.bench.reference_run import run_measured

    wall, rss, rc = run_measured(cmd, env, work / "log.txt")
    if rc != 0 or not result.exists():
        tail = (work / "log.txt").read_text(errors="replace")[-2000:]
        raise RuntimeError(f"{which} run of {name} failed (rc {rc}):\n{tail}")
    rec = json.loads(result.read_text())
    rec.update(process_wall_s=wall, peak_rss_mb=rss)
    if blas is not None:
        rec["blas"] = blas
    rec["measure"], rec["ratio"] = growth(Path(rec.pop("first")), Path(rec.pop("last")))
    return rec


def _median(runs: list[dict], key: str) -> float:
    return float(statistics.median(r[key] for r in runs))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--only", nargs="*", choices=sorted(CASES), default=["cat"])
    ap.add_argument("--runs", type=int, default=2, help="runs of each code, alternating (default 2)")
    ap.add_argument("--child-reference", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--child-idp", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child_reference:
        name, reference, data, work = args.child_reference
        case = CASES[name]
        mesh = Path(data) / "flow" / f"{case.mesh}.obj"
        reference_child(Path(reference), mesh, case, Path(work) / "ref", Path(work) / "result.json")
        return 0
    if args.child_idp:
        name, scene, out = args.child_idp
        idp_child(Path(scene), Path(out), Path(out).parent / "result.json")
        return 0

    if args.output is None:
        ap.error("-o/--output is required")
    from idp.bench.reference_run import find_reference
    from idp.paper_data import find_data_dir

    data = find_data_dir()
    reference = find_reference(data)
    if data is None or reference is None:
        print("the paper's data or the prebuilt reference is missing: no side-by-side flow figures", file=sys.stderr)
        return 2
    args.output.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="idp-flow-ref-"))
    from idp.bench import machine

    report: dict = {"machine": machine.describe(), "runs_per_code": args.runs, "scenes": {}}
    previous = args.output / "flow_reference.json"
    if previous.exists():  # scenes of an earlier invocation into the same folder stay (re-measured ones replaced)
        report["scenes"] = json.loads(previous.read_text()).get("scenes", {})
    for name in args.only:
        case = CASES[name]
        runs: dict[str, list[dict]] = {"reference": [], "idp": []}
        for k in range(args.runs):
            for which in ("reference", "idp"):
                rec = run_once(which, name, case, reference, data, tmp / f"{name}_{which}_{k}")
                runs[which].append(rec)
                print(
                    f"{name} {which} run {k + 1}: {rec['process_wall_s']:.1f} s, {rec['newton_iterations']} its,"
                    f" ratio {rec['ratio']:.4f}",
                    flush=True,
                )
        per_run = [
            r["process_wall_s"] / i["process_wall_s"] for r, i in zip(runs["reference"], runs["idp"], strict=True)
        ]
        report["scenes"][name] = {
            "authors_arguments": {
                "smoothIntensity": case.smooth_intensity,
                "magnitude": case.magnitude,
                "frames": case.frames,
            },
            "idp_scene": f"idp/scenes/paper/{case.scene}",
            "measure": runs["idp"][0]["measure"],
            "runs": runs,
            "speedup_median": _median(runs["reference"], "process_wall_s") / _median(runs["idp"], "process_wall_s"),
            "speedup_per_run": per_run,
        }
        (args.output / "flow_reference.json").write_text(json.dumps(report, indent=1))
    (args.output / "flow_reference.md").write_text(_table(report))
    print(_table(report))
    return 0


def _table(report: dict) -> str:
    from idp.bench.machine import summary as machine_summary

    rows = [
        "| scene | idp process / stepping (s) | reference process / stepping (s) | speed-up (per run) "
        "| Newton its idp / ref | ratio idp / ref | peak RSS MB idp / ref |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, s in report["scenes"].items():
        i, r = s["runs"]["idp"], s["runs"]["reference"]
        rows.append(
            f"| {name} | {_median(i, 'process_wall_s'):.1f} / {_median(i, 'stepping_s'):.1f} "
            f"| {_median(r, 'process_wall_s'):.1f} / {_median(r, 'stepping_s'):.1f} "
            f"| {s['speedup_median']:.2f}× ({', '.join(f'{x:.2f}' for x in s['speedup_per_run'])}) "
            f"| {int(_median(i, 'newton_iterations'))} / {int(_median(r, 'newton_iterations'))} "
            f"| {s['measure']} ×{_median(i, 'ratio'):.4f} / ×{_median(r, 'ratio'):.4f} "
            f"| {_median(i, 'peak_rss_mb'):.0f} / {_median(r, 'peak_rss_mb'):.0f} |"
        )
    return (
        "  \n".join(machine_summary(report["machine"]))
        + f"\n\n{report['runs_per_code']} runs of each code, alternating.\n\n"
        + "\n".join(rows)
        + "\n"
    )


if __name__ == "__main__":
    sys.exit(main())
