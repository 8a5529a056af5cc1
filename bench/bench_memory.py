"""Accuracy of the memory guard's step estimate against measured memory (not a test).

For each size, a scene (3D: a ball of tets growing inside a box; 2D: a triangulated disk growing inside a square)
is built, then run for one step in this process; the peak RSS growth of the run over the RSS after building
(Linux: VmHWM after resetting it through /proc/self/clear_refs) is compared with the largest step estimate of the
run (``summary["memory_estimate"]``). A tiny scene runs first so that numba's compilation is not measured.

    PYTHONPATH=. .venv/bin/python bench/bench_memory.py --dim 3 --solver cholmod --sizes 8 12 16
    PYTHONPATH=. .venv/bin/python bench/bench_memory.py --dim 3 --solver scipy --sizes 8 11 --iterations 3
    PYTHONPATH=. .venv/bin/python bench/bench_memory.py --dim 2 --solver cholmod --sizes 160 240 --iterations 4
"""

from __future__ import annotations

import argparse
import gc
import tempfile
from pathlib import Path

from idp.api import run_built
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _status(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"{key} not in /proc/self/status")


def _scene(dim: int, size: int, solver: str, iterations: int) -> dict:
    if dim == 3:
        body = {"shape": "ball", "radius": 0.3, "resolution": size}
        cage = {"shape": "box_surface", "lo": [-0.32] * 3, "hi": [0.32] * 3, "resolution": 8}
    else:
        body = {"shape": "disk", "radius": 0.3, "resolution": size}
        cage = {"shape": "box_polygon", "lo": [-0.32] * 2, "hi": [0.32] * 2, "resolution": 16}
    return {
        "name": f"mem{dim}d_{size}",
        "dim": dim,
        "time": {"h": 0.0016, "steps": 1},
        "solver": {"newton_tol": 0.1, "linear_solver": solver, "max_newton_iterations": iterations},
        "contact": {"dhat": 2e-3, "dhat_mode": "relative"},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [
            {"name": "body", "generate": body, "rest_shape": {"growth_rate": 0.2, "growth_steps": 3}},
            {"name": "cage", "kind": "obstacle", "generate": cage},
        ],
    }


def measure(dim: int, size: int, solver: str, iterations: int, out: Path) -> dict:
    scene = scene_from_dict(_scene(dim, size, solver, iterations))
    built = build_scene(scene)
    gc.collect()
    before = _status("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")  # reset VmHWM to the current RSS
    result = run_built(scene, built, out / scene.name, progress=False)
    growth = _status("VmHWM") - before
    est = result.summary.get("memory_estimate")
    return {"size": size, "growth": growth, "estimate": est, "iterations": result.summary["newton_iterations"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dim", type=int, choices=[2, 3], default=3)
    ap.add_argument("--solver", choices=["cholmod", "scipy"], default="cholmod")
    ap.add_argument("--sizes", type=int, nargs="+", default=[8, 12])
    ap.add_argument("--iterations", type=int, default=200, help="Newton iteration cap of the one step")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        measure(args.dim, 3 if args.dim == 3 else 8, args.solver, 2, Path(tmp))  # warm-up: compile the kernels
        print("| dim | solver | DOFs | nnz(A) | nnz(L) | measured growth | estimate | estimate / measured |")
        print("|---|---|---|---|---|---|---|---|")
        for size in args.sizes:
            r = measure(args.dim, size, args.solver, args.iterations, Path(tmp))
            est = r["estimate"]
            if est is None:
                print(f"| {args.dim} | {args.solver} | size {size} | no estimate (pymetis missing?) |")
                continue
            print(
                f"| {args.dim}D | {args.solver} | {est['dofs']:,} | {est['matrix_nonzeros']:,} | "
                f"{est['factor_nonzeros']:,} | {r['growth'] / 1e6:,.0f} MB | {est['total_bytes'] / 1e6:,.0f} MB | "
                f"{est['total_bytes'] / r['growth']:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
