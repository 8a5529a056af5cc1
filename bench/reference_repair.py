"""Animation repair (paper §7.3, Fig. 16) by the authors' code on this machine, for a side-by-side timing with idp.

The prebuilt reference (``../shared/reference``) wraps only the §6 scripts in ``run.sh``; its library also holds
the authors' shell repair (``Drivers.FEMDiscreteShellBase`` with ``lv_fn``: each step loads input frame k as the
rest shape, the velocity target and the prescribed head's positions). This script drives it in its own process
with the set-up of the authors' ``16_fix_char_seq.py`` as the data manifest records it (wm2_15k.obj placed by
rotating −90° about +x and translating (0, 0.75, 0); the head box relative (−0.1, 0.867, −0.1)–(1.1, 1.1, 1.1);
density 1000, E 100, ν 0.4, thickness 0.01, bending ×1, d̂ = 1e-2, κ multiplier 1, dt = 0.04, gravity 0, their
default PNTol), one change: ``frame_num`` is the sequence's length (the script's 180 would read past frame 120).
The input frames are written as the OBJ files the script reads (``input/<seq>/k.obj``, exact float64 digits).
Reports the process wall (launch to exit), the stepping wall, Newton iterations and peak RSS, and writes the
repaired frames as ``<seq>_reference.npz`` for ``bench/repair_vs_authors.py``. No code of the reference is
copied: its library is called through its own Python API, only its printed and written results are read.

    .venv/bin/python bench/reference_repair.py -o bench/results/repair_ref --seq Kick [--frames 120]

The reference runs with ``OMP_NUM_THREADS=OPENBLAS_NUM_THREADS=2``; run idp's committed scene
(``idp run idp/scenes/paper/fig16_repair_kick.toml``) on the same idle machine for the comparison.
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


def _write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += [f"f {a} {b} {c}" for a, b, c in (faces + 1).tolist()]
    path.write_text("\n".join(lines) + "\n")


def reference_child(reference: Path, data: Path, seq: str, frames: int, work: Path, result: Path) -> None:
    """In the reference's process: the authors' repair set-up, then a JSON record of what it did."""
    root = work / "Projects" / "FEMShell"
    inp = root / "input"
    scripts = root / "scripts"
    (inp / f"{seq}_unfixed").mkdir(parents=True)
    scripts.mkdir(parents=True)
    (inp / "wm2_15k.obj").symlink_to(data / "repair" / "wm2_15k.obj")
    with np.load(data / "repair" / f"{seq}_unfixed.npz") as d:
        V = np.ascontiguousarray(d["vertices"], dtype=float)
        F = np.asarray(d["faces"], dtype=np.int64)
    for k in range(frames + 1):
        _write_obj(inp / f"{seq}_unfixed" / f"{k}.obj", V[k], F)
    os.chdir(scripts)
    sys.path[:0] = [str(reference / "stubs"), str(reference / "Python"), str(reference / "lib")]
    sys.argv = ["16_fix_char_seq.py", f"{seq}_unfixed", "1e-2", "1"]
    import Drivers  # type: ignore[import-not-found]
    from JGSL import FEM, Storage, Vector3d, Vector4i  # type: ignore[import-not-found]

    sim = Drivers.FEMDiscreteShellBase("double", 3)
    sim.add_shell_with_scale_3D(
        "../input/wm2_15k.obj", Vector3d(0, 0.75, 0), Vector3d(1, 1, 1), Vector3d(0, 0, 0), Vector3d(1, 0, 0), -90
    )
    zero = Vector3d(0, 0, 0)
    # the script's sim.set_DBC(...), called straight: the prebuilt (modeling-branch) library's Init_Dirichlet takes
    # one more argument (scaleVel, 0 here) and another motion storage than this driver passes it
    sim.DBCMotion = Storage.V2iV3dV3dV3dSdSdStorage()
    FEM.Init_Dirichlet(
        sim.X, Vector3d(-0.1, 0.867, -0.1), Vector3d(1.1, 1.1, 1.1), zero, zero, Vector3d(1, 0, 0), 0.0, 0.0,
        sim.DBC, sim.DBCMotion, Vector4i(0, 0, 1000000000, -1),
    )  # fmt: skip
    sim.dt = 0.04
    sim.frame_dt = 0.04
    sim.frame_num = frames
    sim.withCollision = True
    sim.gravity = zero
    sim.initialize(1000, 100, 0.4, 0.01, 0)
    sim.bendingStiffMult = 1
    sim.initialize_OIPC(1e-2, 0, 1)
    sim.lv_fn = 1
    sim.seqDBCPath = f"../input/{seq}_unfixed"
    # The head box has no motion of its own (the frames move it): no Step_Dirichlet, as bench/reference_flow.py.
    sim.MDBC_tmax = -1
    t0 = time.perf_counter()
    sim.run()
    stepping = time.perf_counter() - t0
    out = scripts / sim.output_folder
    record = {"stepping_s": stepping, "newton_iterations": int(sim.PNIterCount), "output": str(out)}
    result.write_text(json.dumps(record))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--seq", choices=["Kick", "Rumba_Dancing"], default="Kick")
    ap.add_argument("--frames", type=int, default=120, help="steps (input frames 1..N; default 120: all)")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        reference, data, seq, frames, work = args.child
        reference_child(Path(reference), Path(data), seq, int(frames), Path(work) / "ref", Path(work) / "result.json")
        return 0
    if args.output is None:
        ap.error("-o/--output is required")
    from idp.bench.data import require_data_dir
    from idp.bench.machine import describe
    from idp.bench.reference_run import find_reference, run_measured

    data = require_data_dir()
    reference = find_reference(data)
    if reference is None:
        print("reference_repair: the authors' reference code was not found (IDP_REFERENCE)", file=sys.stderr)
        return 2
    work = args.output.resolve()
    work.mkdir(parents=True, exist_ok=False)
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", PYTHONDONTWRITEBYTECODE="1")
    from idp.bench.reference_blas import choose_reference_blas

    env, blas = choose_reference_blas(env)  # its OpenBLAS on kernels for this CPU (idp/bench/reference_blas.py)
    cmd = [sys.executable, "-B", __file__, "--child", str(reference), str(data), args.seq, str(args.frames), str(work)]
    wall, peak_mb, rc = run_measured(cmd, env, work / "log.txt")
    result = work / "result.json"
    if rc != 0 or not result.exists():
        print((work / "log.txt").read_text(errors="replace")[-3000:], file=sys.stderr)
        return 1
    rec = json.loads(result.read_text())
    out = Path(rec.pop("output"))
    import meshio

    frames = [np.asarray(meshio.read(out / f"shell{k}.obj").points, dtype=float) for k in range(args.frames + 1)]
    with np.load(data / "repair" / f"{args.seq}_unfixed.npz") as d:
        faces = np.asarray(d["faces"], dtype=np.int32)
    np.savez_compressed(work / f"{args.seq}_reference.npz", vertices=np.stack(frames), faces=faces)
    rec.update(
        blas=blas,
        process_wall_s=wall,
        peak_rss_mb=peak_mb,
        frames=args.frames,
        seq=args.seq,
        machine=describe(),
    )
    (work / "reference_repair.json").write_text(json.dumps(rec, indent=1))
    print(json.dumps(rec, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
