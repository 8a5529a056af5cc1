"""Filling both bulbs of the hourglass (Fig. 9) by growing in stages, re-tetrahedralised finer between stages.

    .venv/bin/python bench/hourglass_remesh.py [-o bench/results/hourglass_remesh]   # the committed scene
    .venv/bin/python bench/hourglass_remesh.py --which bunny_700 [--stages 2] [--stage-steps 10]
        [--stage-growth 0.2] [--max-volume 3e-6] [--newton-tol 0.1] [--yield-stress 0]   # a generated variant
    .venv/bin/python bench/hourglass_remesh.py --measure OUT   # a finished `idp run` of a staged hourglass

The committed scene ``idp/scenes/paper/fig09_hourglass_staged.toml`` (or a variant generated from
``idp.bench.scenes.hourglass``: ``--which bunny`` the 13K bunny × 0.05, ``bunny_700`` the coarse stand-in) first grows
the object as the suite does (×3 over 20 steps); then, stage after stage, its current shape is baked into its rest
shape and re-tetrahedralised with the surface split in its own plane (``bake_remesh``, TetGen: ``idp[remesh]``) to
tets no larger than ``--max-volume`` — elements a few times smaller than the neck's radius (≈ 0.03), where the grown
object's are as wide as it — and its rest shape grows again by ``--stage-growth`` (linear) over the next stage.
Each stage is a stage of one idp scene, so every frame is certified as in any run. Writes ``results.json`` and
``results.md``: per stage its steps, Newton iterations, the object's mesh at its end, the fill, the highest vertex
(neck at y ≈ 0.30, upper bulb 0.30–0.75) and the share of the object's volume above the neck. Needs the paper's
data ($IDP_DATA or ../shared/data).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

NECK_Y = 0.30


def staged_scene(
    which: str, stages: int, stage_steps: int, growth: float, max_volume: float, yield_stress: float, newton_tol: float
):
    from idp.bench.data import require_data_dir
    from idp.bench.scenes import hourglass

    d = hourglass(require_data_dir(), which, steps=20, newton_tol=newton_tol).model_dump(mode="json", exclude_none=True)
    d["name"] = f"hourglass_{which}_staged_remesh"
    d["time"]["stop_when_stationary"] = False
    d["output"].update({"every": 1, "obj": True, "vtu": False, "png": False})
    body = d["objects"][0]
    if yield_stress > 0:
        body["plasticity"] = {"yield_stress": yield_stress}
    name = body["name"]
    remesh = {"quality": 1.5, "max_volume": max_volume, "refine_surface": True}
    d["stages"] = [{"name": "grow", "steps": 20, "after": {name: "bake_remesh"}, "remesh": remesh}]
    for k in range(1, stages + 1):
        d["stages"].append(
            {
                "name": f"push{k}",
                "steps": stage_steps,
                "set": {
                    name: {
                        "rest_scripts": [
                            {"type": "scale", "start": 0, "end": stage_steps, "rate": growth / stage_steps}
                        ]
                    }
                },
                "after": {name: "bake_remesh"} if k < stages else {},
                "remesh": remesh,
            }
        )
    return d


def volume_above(vertices, tets, y: float) -> float:
    """Volume of the tets whose centroid lies above height ``y``."""
    import numpy as np

    p = vertices[tets]
    e1, e2, e3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    vol = np.abs(np.einsum("ij,ij->i", e1, np.cross(e2, e3))) / 6.0
    return float(vol[p[:, :, 1].mean(axis=1) > y].sum())


def measure(run: Path) -> dict:
    """Per finished stage of the staged run in ``run``: steps, Newton iterations, mesh size, fill, the highest
    vertex and the share of the object's volume above the neck (from the stage's end shape); certified or not."""
    import meshio
    import numpy as np

    rows, fills = [], []
    for sdir in sorted((run / "stages").iterdir()):
        if not (sdir / "stage.json").exists():
            continue
        st = json.loads((sdir / "stage.json").read_text())
        summ = st["summary"]
        recs = json.loads((sdir / "stats.json").read_text())["steps"]
        fill = [r.get("fill_fraction") for r in recs if r.get("step", 0) > 0]
        fills += fill
        obj = next(iter(st["objects"].values()))
        mesh = meshio.read(obj["mesh"])
        tets = mesh.cells_dict["tetra"]
        share = volume_above(mesh.points, tets, NECK_Y) / volume_above(mesh.points, tets, -np.inf)
        rows.append(
            {
                **{k: summ.get(k) for k in ("stage", "steps", "newton_iterations", "wall_time", "all_certified")},
                "object_vertices": int(mesh.points.shape[0]),
                "object_tets": int(tets.shape[0]),
                "fill": fill[-1] if fill else None,
                "top_y": float(mesh.points[:, 1].max()),
                "share_above_neck": share,
                "min_distance": summ.get("min_distance"),
            }
        )
    return {"stages": rows, "fill_per_step": fills, "all_certified": all(r["all_certified"] for r in rows)}


def table(rows: list[dict]) -> str:
    lines = [
        "| stage | steps | Newton its | wall (s) | object vertices / tets at its end | fill | top y "
        "| object volume above the neck | certified |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['stage']} | {r['steps']} | {r['newton_iterations']} | {r['wall_time']:.0f} "
            f"| {r['object_vertices']} / {r['object_tets']} | {100 * (r['fill'] or 0):.2f} % | {r['top_y']:.3f} | "
            f"{100 * r['share_above_neck']:.1f} % | {r['all_certified']} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="bench/results/hourglass_remesh")
    ap.add_argument("--measure", metavar="RUN", help="only measure a finished (staged) run folder")
    ap.add_argument(
        "--which",
        default=None,
        choices=["bunny_700", "bunny"],
        help="a generated variant (default: the committed scene fig09_hourglass_staged.toml)",
    )
    ap.add_argument("--stages", type=int, default=2, help="push stages after the growth (generated variant)")
    ap.add_argument("--stage-steps", type=int, default=10)
    ap.add_argument("--stage-growth", type=float, default=0.2, help="linear rest-shape growth per stage")
    ap.add_argument("--max-volume", type=float, default=3e-6, help="largest tet after each remesh")
    ap.add_argument("--yield-stress", type=float, default=0.0, help="plastic yield stress (0: elastic)")
    ap.add_argument("--newton-tol", type=float, default=0.1, help="the suite's hourglass uses 1")
    a = ap.parse_args()

    import idp
    from idp.bench.scenes import PAPER_SCENES
    from idp.scene.load import load_scene, scene_from_dict

    out = Path(a.output)
    out.mkdir(parents=True, exist_ok=True)
    wall = None
    if a.measure:
        run = Path(a.measure)
    else:
        run = out / "run"
        if a.which:
            d = staged_scene(
                a.which, a.stages, a.stage_steps, a.stage_growth, a.max_volume, a.yield_stress, a.newton_tol
            )
            (out / "scene.json").write_text(json.dumps(d, indent=1))
            scene = scene_from_dict(d)
        else:
            scene = load_scene(PAPER_SCENES / "fig09_hourglass_staged.toml")
        t0 = time.perf_counter()
        idp.simulate(scene, run, progress=True)
        wall = time.perf_counter() - t0
    result = {"settings": vars(a), "wall_s": wall, **measure(run)}
    (out / "results.json").write_text(json.dumps(result, indent=1))
    (out / "results.md").write_text(table(result["stages"]) + "\n")
    print(table(result["stages"]))


if __name__ == "__main__":
    main()
