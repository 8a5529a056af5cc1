"""Pictures and a summary table of the paper-figure runs (Figs. 3 and 10) from their output folders.

    python bench/paper_figures.py fig10 OUT_PLASTIC OUT_ELASTIC OUT_NOBARRIER -o docs/figures/fig10_bar.png
    python bench/paper_figures.py fig03 OUT_ARMADILLO -o docs/figures/fig03_armadillo.png --frames 0 25 54 120
    python bench/paper_figures.py table OUT... > table.md

Positions are read back from each run's VTU frames (every point of the scene) and drawn with the parts of the
scene the run resolved (``scene.resolved.json``), so the pictures show exactly what was written and certified.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import meshio
import numpy as np

from idp.output.render import render_frames_png
from idp.output.stats import load_stats
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _parts(run: Path):
    resolved = json.loads((run / "scene.resolved.json").read_text())
    return build_scene(scene_from_dict(resolved)).system.parts


def _frame(run: Path, step: int) -> np.ndarray:
    return meshio.read(run / "vtu" / f"frame_{step:05d}.vtu").points


def _last_step(run: Path) -> int:
    return int(load_stats(run / "stats.json")["summary"]["last_step"])


def summary_row(run: Path) -> str:
    st = load_stats(run / "stats.json")
    s, recs = st["summary"], [r for r in st["steps"] if not r.get("initial")]
    pairs = max((r["certificate"].get("intersecting_pairs", 0) for r in recs), default=0)
    guarded = all(r["certificate"].get("guards_intersection", True) for r in recs)
    mind = s["min_distance"]
    return (
        f"| {st['meta'].get('scene', run.name)} | {s['steps_run']} | {s['wall_time']:.0f} | {s['newton_iterations']} "
        f"| {s.get('steps_with_unmet_targets', 0)} | {mind if isinstance(mind, str) else f'{mind:.2e}'} "
        f"| {'yes' if s['all_certified'] and guarded else ('no barrier: ' + str(pairs) + ' crossing pairs max')} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("fig10", "fig03", "table"))
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--frames", nargs="*", type=int, default=None)
    ap.add_argument("--view", nargs=2, type=float, default=(20.0, -60.0))
    a = ap.parse_args()
    if a.what == "table":
        print("| scene | steps | wall (s) | Newton its | steps with unmet BC | min distance | every frame certified |")
        print("|---|---|---|---|---|---|---|")
        for r in a.runs:
            print(summary_row(r))
        return
    a.output.parent.mkdir(parents=True, exist_ok=True)
    if a.what == "fig10":
        parts = _parts(a.runs[0])
        titles = ["elasto-plastic, barrier", "elastic, barrier", "elastic, no barrier"]
        frames = [(t, _frame(r, _last_step(r))) for t, r in zip(titles, a.runs, strict=True)]
        render_frames_png(a.output, parts, frames, dim=3, view=tuple(a.view), size=(1500, 520))
    else:
        run = a.runs[0]
        parts = _parts(run)
        steps = a.frames or [0, _last_step(run)]
        frames = [(f"step {k}", _frame(run, k)) for k in steps]
        cols = len(frames)
        render_frames_png(a.output, parts, frames, dim=3, view=tuple(a.view), size=(380 * cols, 480))
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
