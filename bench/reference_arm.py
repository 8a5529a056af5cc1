"""The Fig. 20 arm (paper §7.4) bent by the authors' code and by idp, in turn, on this machine.

The prebuilt reference (``../shared/reference``) is the authors' ``modeling`` branch: its library has the
symmetric Dirichlet energy (``Elasticity_model = "SD"``, p = 1) but not the minmax branch's p-norm (``SD5``).
The modeling branch's own arm script (``_fig20_arm.py``) bends ``arm10K`` with SD; the data manifest
(``handles/``) records its set-up: identity placement, E 1e5 (the minmax branch's ``arm_thicker`` uses 2e4),
ν 0.4, density 1000, dt = frame dt = 0.04, 100 frames, d̂² = 1e-6, three thin cores along the axis given as boxes
relative to the bounding box — the left one turning at −20°/s and the right one at +20°/s about the z axis
through the origin, the middle one fixed. This script drives that set-up through the library's own Python API
in a separate process (no code of the reference is copied: only its results are read), dumps the tets after
every frame (the authors' ``Write_TetMesh_Vtk``, 6 significant digits), and runs idp's committed scene of the
same mesh with the same E and power. Both codes' frames are measured by one function: Ψ = ‖F‖² + ‖F⁻¹‖² per
tet (6 at rest), its worst / 99th percentile / mean at chosen steps, plus Newton iterations and wall time.

    .venv/bin/python bench/reference_arm.py -o bench/results/arm_ref [--mesh arm10K] [--youngs 1e5] \\
        [--pntol 1e-2] [--frames 100] [--which reference idp]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# relative boxes of the three cores: (x range, y/z range) per mesh, as the data manifest gives them
CORE_YZ = {"arm10K": (0.45, 0.55), "arm_thicker": (0.47, 0.53)}
CORES = [((-0.1, 0.46), -20.0, "left_bone"), ((0.54, 1.1), 20.0, "right_bone"), ((0.49, 0.51), 0.0, "centre")]
SCENES = {"arm10K": "fig20_arm10K_sd1.toml", "arm_thicker": "fig20_arm_thicker_sd1.toml"}


def read_vtk_tets(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points and tets of a legacy ASCII VTK unstructured grid (the authors' dump)."""
    tokens = path.read_text().split()
    i = tokens.index("POINTS")
    n = int(tokens[i + 1])
    pts = np.array(tokens[i + 3 : i + 3 + 3 * n], dtype=float).reshape(n, 3)
    j = tokens.index("CELLS")
    m = int(tokens[j + 1])
    cells = np.array(tokens[j + 3 : j + 3 + 5 * m], dtype=np.int64).reshape(m, 5)
    return pts, cells[:, 1:]


def sd_psi(rest: np.ndarray, x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Ψ = ‖F‖² + ‖F⁻¹‖² per tet (idp's measure, as its runs report it; +inf where det F ≤ 0)."""
    from idp.mesh.distortion import symmetric_dirichlet_distortion

    Dm = np.stack([rest[tets[:, k]] - rest[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    Ds = np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    return symmetric_dirichlet_distortion(Ds @ np.linalg.inv(Dm))


def tet_volumes(rest: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (rest[tets[:, k]] for k in range(4))
    return np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0


def summary(psi: np.ndarray, volumes: np.ndarray) -> dict:
    """Worst, 99th percentile, volume-weighted mean, as idp's stats report them."""
    from idp.mesh.distortion import distortion_summary

    s = distortion_summary(psi, volumes)
    return {k: s[k] for k in ("worst", "p99", "mean", "infinite")}


# ---------------------------------------------------------------------------------------------------------------
# children


def reference_child(
    reference: Path, mesh: Path, name: str, youngs: float, pntol: float, frames: int, work: Path
) -> None:
    """In the reference's process: the authors' arm set-up; a tet dump and a JSON line per frame."""
    scripts = work / "Projects" / "FEM" / "scripts"
    scripts.mkdir(parents=True)
    (work / "Projects" / "FEM" / "input").mkdir(parents=True)
    (work / "Projects" / "FEM" / "input" / mesh.name).symlink_to(mesh)
    os.chdir(scripts)
    sys.path[:0] = [str(reference / "stubs"), str(reference / "Python"), str(reference / "lib")]
    sys.argv = ["_fig20_arm.py", name]
    import Drivers  # type: ignore[import-not-found]
    from JGSL import MeshIO, Set_Parameter, Vector3d  # type: ignore[import-not-found]

    sim = Drivers.FEMSimulationBase("double", 3, "SD")
    zero = Vector3d(0, 0, 0)
    sim.add_object(f"../input/{mesh.name}", zero, zero, Vector3d(1, 0, 0), 0, Vector3d(1, 1, 1))
    lo, hi = CORE_YZ[name]
    for (x0, x1), deg, _ in CORES:
        sim.set_DBC(Vector3d(x0, lo, lo), Vector3d(x1, hi, hi), zero, zero, Vector3d(0, 0, 1), deg)
    sim.initialize_added_objects(zero, 1000, youngs, 0.4)
    Set_Parameter("Target_Psi", "NO")
    sim.PNTol = pntol
    sim.dt = sim.frame_dt = 0.04
    sim.frame_num = frames
    sim.gravity = zero
    sim.initialize_OIPC(1e-6)
    dumps = work / "tets"
    dumps.mkdir()
    log = open(work / "frames.jsonl", "w", buffering=1)
    state = {"its": sim.PNIterCount, "t": time.perf_counter()}
    orig_write = type(sim).write

    def write(self, frame_idx):
        orig_write(self, frame_idx)
        MeshIO.Write_TetMesh_Vtk(self.X, self.Elem, str(dumps / f"{frame_idx}.vtk"))
        now = time.perf_counter()
        rec = {"frame": frame_idx, "newton_iterations": self.PNIterCount - state["its"], "wall_s": now - state["t"]}
        log.write(json.dumps(rec) + "\n")
        state["its"], state["t"] = self.PNIterCount, time.perf_counter()

    type(sim).write = write
    sim.run()


def idp_child(scene_path: Path, youngs: float, frames: int, out: Path) -> None:
    """In idp's process: the committed scene with the reference's E and frame count."""
    from idp.cli import _set_threads

    _set_threads(2)
    from idp.api import simulate
    from idp.scene.load import load_scene

    scene = load_scene(scene_path)
    obj = scene.objects[0]
    assert obj.material is not None, f"{scene_path}: the arm has no material"
    obj = obj.model_copy(update={"material": obj.material.model_copy(update={"youngs_modulus": youngs})})
    scene = scene.model_copy(
        update={
            "objects": [obj],
            "time": scene.time.model_copy(update={"steps": frames}),
            "output": scene.output.model_copy(update={"obj": False, "png": False}),
        }
    )
    simulate(scene, out, progress=False)


# ---------------------------------------------------------------------------------------------------------------
# parent


def measure_reference(work: Path, rest: np.ndarray, tets: np.ndarray) -> dict:
    """Newton iterations, stepping time and Ψ of every frame the reference dumped."""
    frames = [json.loads(line) for line in (work / "frames.jsonl").read_text().splitlines()]
    vol = tet_volumes(rest, tets)
    per_step = []
    for f in frames[1:]:
        x, t = read_vtk_tets(work / "tets" / f"{f['frame']}.vtk")
        assert np.array_equal(t, tets), "the reference's tets differ from the mesh file's"
        per_step.append({"step": f["frame"], "newton_iterations": f["newton_iterations"], "wall_s": f["wall_s"]})
        per_step[-1].update(summary(sd_psi(rest, x, tets), vol))
    return {
        "newton_iterations": sum(f["newton_iterations"] for f in frames),
        "stepping_s": sum(f["wall_s"] for f in frames[1:]),
        "steps": len(frames) - 1,
        "per_step": per_step,
    }


def measure_idp(out_dir: Path, rest: np.ndarray, tets: np.ndarray) -> dict:
    """Newton iterations, stepping time, certificates and Ψ of every frame of an idp run (its VTU frames)."""
    import meshio

    stats = json.loads((out_dir / "stats.json").read_text())
    steps = stats["steps"][1:]
    vtus = sorted((out_dir / "vtu").glob("*.vtu"))
    vol = tet_volumes(rest, tets)
    per_step = []
    for s, path in zip(steps, vtus[1:], strict=False):
        x = np.asarray(meshio.read(path).points, dtype=float)
        per_step.append({"step": s["step"], "newton_iterations": s["newton_iterations"], "wall_s": s["wall_time"]})
        per_step[-1].update(summary(sd_psi(rest, x, tets), vol))
        per_step[-1]["targets_met"] = bool((s.get("dirichlet") or {}).get("met", True))
    return {
        "newton_iterations": sum(s["newton_iterations"] for s in steps),
        "stepping_s": sum(s["wall_time"] for s in steps),
        "steps": len(steps),
        "all_certified": all(s["certificate"]["ok"] for s in stats["steps"]),
        "per_step": per_step,
    }


def plot(results: dict, path: Path) -> None:
    """Worst Ψ against the step, both codes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for which, style in (("reference", "k--"), ("idp", "C0-")):
        rec = results.get(which)
        if isinstance(rec, dict):
            steps = [r["step"] for r in rec["per_step"]]
            ax.plot(steps, [r["worst"] for r in rec["per_step"]], style, label=f"{which}: worst Ψ")
            ax.plot(steps, [r["p99"] for r in rec["per_step"]], style, alpha=0.4, label=f"{which}: 99th percentile")
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("Ψ_SD (6 = isometry)")
    ax.set_title(f"{results['mesh']}, symmetric Dirichlet, E = {results['youngs_modulus']:g}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def table(results: dict, at: list[int]) -> str:
    """Markdown: per code, Newton iterations, stepping time, worst Ψ at the chosen steps, p99 at the last."""
    lines = [
        "| code | steps | Newton its | stepping (s) | worst Ψ at " + " / ".join(map(str, at)) + " | p99 at the last |",
        "|---|---|---|---|---|---|",
    ]
    for which in ("reference", "idp"):
        rec = results.get(which)
        if not isinstance(rec, dict):
            continue
        by = {r["step"]: r for r in rec["per_step"]}
        worst = " / ".join(f"{by[k]['worst']:.2f}" if k in by else "—" for k in at)
        last = rec["per_step"][-1]
        lines.append(
            f"| {which} | {rec['steps']} | {rec['newton_iterations']} | {rec['stepping_s']:.0f} | {worst} | "
            f"{last['p99']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--mesh", choices=sorted(CORE_YZ), default="arm10K")
    ap.add_argument("--youngs", type=float, default=1e5)
    ap.add_argument("--pntol", type=float, default=1e-2, help="the reference's PNTol (its driver's default 1e-2)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--which", nargs="+", choices=["reference", "idp"], default=["reference", "idp"])
    ap.add_argument(
        "--measure-only",
        action="store_true",
        help="run nothing: measure the runs already in OUTPUT/reference and OUTPUT/idp (e.g. a resumed idp run)",
    )
    ap.add_argument("--child-reference", nargs=7, help=argparse.SUPPRESS)
    ap.add_argument("--child-idp", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child_reference:
        ref, mesh, name, E, tol, frames, work = args.child_reference
        reference_child(Path(ref), Path(mesh), name, float(E), float(tol), int(frames), Path(work))
        return 0
    if args.child_idp:
        scene, E, frames, out = args.child_idp
        idp_child(Path(scene), float(E), int(frames), Path(out))
        return 0
    if args.output is None:
        ap.error("-o/--output is required")
    args.output = args.output.resolve()

    reference = Path(os.environ.get("IDP_REFERENCE", HERE.parent.parent / "shared" / "reference")).resolve()
    data = Path(os.environ.get("IDP_DATA", HERE.parent.parent / "shared" / "data")).resolve()
    mesh = data / "handles" / f"{args.mesh}.vtk"
    import meshio

    m = meshio.read(mesh)
    rest = np.asarray(m.points, dtype=float)
    tets = np.asarray(m.cells_dict["tetra"], dtype=np.int64)
    at = sorted({k for k in (25, 50, 75, args.frames) if k <= args.frames})
    args.output.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", PYTHONDONTWRITEBYTECODE="1")
    results: dict = {"mesh": args.mesh, "youngs_modulus": args.youngs, "frames": args.frames, "pntol": args.pntol}
    for which in args.which:
        work = args.output / which
        wall = rss = rc = None
        if not args.measure_only:
            if which == "reference" and not reference.exists():
                results[which] = "unavailable: no ../shared/reference"
                continue
            if which == "reference":
                cmd = [sys.executable, "-B", __file__, "--child-reference", str(reference), str(mesh), args.mesh]
                cmd += [str(args.youngs), str(args.pntol), str(args.frames), str(work)]
            else:
                scene = HERE.parent / "idp" / "scenes" / "paper" / SCENES[args.mesh]
                cmd = [sys.executable, __file__, "--child-idp", str(scene), str(args.youngs), str(args.frames)]
                cmd.append(str(work))
            from idp.bench.reference_run import run_measured

            run_env, blas = env, None
            if which == "reference":
                from idp.bench.reference_blas import choose_reference_blas

                run_env, blas = choose_reference_blas(env)  # kernels for this CPU (idp/bench/reference_blas.py)
            wall, rss, rc = run_measured(cmd, run_env, args.output / f"{which}.log")
        if not work.exists():
            results[which] = f"no run in {work}"
            continue
        rec = measure_reference(work, rest, tets) if which == "reference" else measure_idp(work, rest, tets)
        rec.update(process_wall_s=wall, peak_rss_mb=rss, exit_code=rc)
        if which == "reference" and not args.measure_only:
            rec["blas"] = blas
        results[which] = rec
        (args.output / "arm_vs_reference.json").write_text(json.dumps(results, indent=1))
    (args.output / "arm_vs_reference.md").write_text(table(results, at))
    plot(results, args.output / "arm_vs_reference.png")
    print(table(results, at), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
