"""Does a handle step cost more than a growth step of the same size? (issue: handles, §4.3 speed target)

Same mesh (the Fig. 10 bar, 7,287 vertices / 27,444 tets), same material, same number of steps, no contact in
reach: (a) both end caps turned by handles (the §4.3 path: feasible move, penalty, held rows), (b) the caps
pinned and the rest shape grown by 1 % per step (the existing growth path). Prints and writes per-Newton-
iteration timings of both.

    .venv/bin/python bench/bench_handles.py -o bench/results/handles [--steps 10]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from idp.api import simulate
from idp.bench.machine import describe
from idp.bench.scenes import paper_scene
from idp.scene.schema import FixedSelector


def _per_iteration(res) -> dict:
    its = max(res.summary["newton_iterations"], 1)
    return {k: v / its for k, v in res.summary["timings"].items()} | {"iterations": its}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results/handles"))
    ap.add_argument("--steps", type=int, default=10)
    a = ap.parse_args()
    a.output.mkdir(parents=True, exist_ok=True)

    handles = paper_scene("fig10_bar_elastic.toml", steps=a.steps)
    growth = paper_scene("fig10_bar_elastic.toml", steps=a.steps)
    bar = growth.objects[0]
    bar.fixed = [FixedSelector(box=h.select.box, relative=True) for h in bar.handles[:2]]  # same caps, pinned
    bar.handles = []
    bar.rest_shape.growth_rate, bar.rest_shape.growth_steps = 0.01, a.steps

    out = {"machine": describe(), "steps": a.steps}
    for name, scene in (("handles", handles), ("growth", growth)):
        t = time.perf_counter()
        res = simulate(scene, a.output / name, progress=False)
        out[name] = {"wall": time.perf_counter() - t, "per_iteration": _per_iteration(res)}
    (a.output / "handles_vs_growth.json").write_text(json.dumps(out, indent=2))
    keys = ["assembly", "linear_solve", "ccd", "line_search", "contact_build", "certificate", "other"]
    print("| run | Newton its | " + " | ".join(f"{k} (ms/it)" for k in keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for name in ("handles", "growth"):
        p = out[name]["per_iteration"]
        print(f"| {name} | {p['iterations']} | " + " | ".join(f"{1000 * p.get(k, 0.0):.1f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
