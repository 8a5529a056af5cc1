"""What lets a growing object pass the hourglass neck (Fig. 9)? Variants of the coarse stand-in scene.

    .venv/bin/python bench/hourglass_neck.py [VARIANT ...] [-o bench/results/hourglass_neck]

Each variant is the stand-in of ``idp.bench.scenes.hourglass(data, "bunny_700")`` (bunny_700 × 1.5 grown ×3 over
20 steps in hourglass.obj) with one change: plasticity, continued growth, a bake of the rest shape every step, a
tighter Newton tolerance. Writes ``VARIANT.json`` per variant and ``results.md``: steps, Newton iterations, fill,
the highest vertex of the object (the neck is at y ≈ 0.30, the upper bulb spans 0.30–0.75) and how many of its
vertices are above the neck, every frame certified or not. Needs the paper's data ($IDP_DATA or ../shared/data).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

NECK_Y = 0.30

# name -> (steps, growth steps, plastic yield stress or None, bake every step, Newton tolerance)
VARIANTS: dict[str, tuple[int, int, float | None, bool, float]] = {
    "elastic": (40, 20, None, False, 1.0),
    "plastic_1e3": (40, 20, 1e3, False, 1.0),
    "plastic_1e2": (40, 20, 1e2, False, 1.0),
    "plastic_1e2_grow40": (60, 40, 1e2, False, 1.0),
    "plastic_1e2_grow40_150": (150, 40, 1e2, False, 1.0),
    "plastic_1e2_grow40_tol001_150": (150, 40, 1e2, False, 0.01),
    "bake_every_step": (300, 300, None, True, 1.0),
    "bake_every_step_tol001": (100, 100, None, True, 0.01),
}


def run_variant(name: str, out: Path, which: str = "bunny_700") -> dict:
    import numpy as np

    import idp
    from idp.bench.data import require_data_dir
    from idp.bench.scenes import hourglass
    from idp.scene.load import scene_from_dict

    steps, growth_steps, yield_stress, bake, tol = VARIANTS[name]
    d = hourglass(require_data_dir(), which, steps=steps).model_dump(mode="json", exclude_none=True)
    d["time"]["stop_when_stationary"] = False
    d["solver"]["newton_tol"] = tol
    d["output"]["every"] = 10
    body = d["objects"][0]
    body["rest_shape"]["growth_steps"] = growth_steps
    if yield_stress is not None:
        body["plasticity"] = {"yield_stress": yield_stress}
    if bake:
        body["rest_scripts"] = [{"type": "bake", "step": k} for k in range(1, steps + 1)]
    t0 = time.perf_counter()
    res = idp.simulate(scene_from_dict(d), out / name, progress=False)
    recs = res.step_records
    from idp.output.stats import load_stats

    n = load_stats(out / name / "stats.json")["meta"]["num_dynamic_vertices"]  # the object's vertices come first
    y = res.x[:n, 1]
    result = {
        "variant": name,
        "steps": len(recs),
        "growth_steps": growth_steps,
        "yield_stress": yield_stress,
        "bake_every_step": bake,
        "newton_tol": tol,
        "wall": time.perf_counter() - t0,
        "newton_iterations": sum(r["newton_iterations"] for r in recs),
        "fill": res.summary["fill_fraction"],
        "fill_per_step": [r["fill_fraction"] for r in recs],
        "top_y": float(y.max()),
        "vertices_above_neck": int(np.count_nonzero(y > NECK_Y + 0.05)),
        "vertices": int(y.size),
        "certified": all(r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"] for r in recs),
    }
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", help=f"default: all of {', '.join(VARIANTS)}")
    ap.add_argument("-o", "--output", default="bench/results/hourglass_neck")
    ap.add_argument(
        "--which", default="bunny_700", choices=["bunny_700", "bunny"], help="the stand-in, or the 13K bunny (× 0.05)"
    )
    a = ap.parse_args()
    unknown = sorted(set(a.variants) - set(VARIANTS))
    if unknown:
        ap.error(f"unknown variant(s) {unknown}; choose from {list(VARIANTS)}")
    out = Path(a.output)
    out.mkdir(parents=True, exist_ok=True)
    rows = [
        "| variant | steps (growth) | plasticity σ_Y | bake every step | Newton tol | Newton its | fill | top y "
        "| vertices above the neck | certified |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in a.variants or list(VARIANTS):
        r = run_variant(name, out, a.which)
        print(f"{name}: fill {100 * r['fill']:.2f} %, top y {r['top_y']:.3f}, {r['newton_iterations']} its", flush=True)
        rows.append(
            f"| {name} | {r['steps']} ({r['growth_steps']}) | {r['yield_stress'] or '–'} | {r['bake_every_step']} "
            f"| {r['newton_tol']} | {r['newton_iterations']} | {100 * r['fill']:.2f} % | {r['top_y']:.3f} "
            f"| {r['vertices_above_neck']} / {r['vertices']} | {r['certified']} |"
        )
    (out / "results.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
