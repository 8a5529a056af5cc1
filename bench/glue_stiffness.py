"""How far a glued dumpling's seam opens when another lands on it, for a few glue stiffnesses (Fig. 21).

    .venv/bin/python bench/glue_stiffness.py [--stiffness 1 10] [--threads 1] [-o bench/results/glue_stiffness]

Two of ``fig21_our_dumplings_on_plate.toml``'s dumplings, the manifest's placements 2 and 6 (one above the other,
at (−0.05, 0.1456, 0.05) and (−0.05, 1.28, 0.05)), dropped onto the plate without the pusher: the lower one lands
at step 10, the upper one lands on it at step 79. Everything else is that scene's (our Fig. 1 result, E 1e4,
gravity, d̂ 4e-5, the glue's link radius 2e-3); only ``[sticky] stiffness`` changes (the committed scene keeps the
authors' 1). A link's stretch is |its length − its rest length|: how far the two lips it joins have moved apart
(they started 2e-4 to 2e-3 apart), so the largest stretch is how far a seam opened. Writes ``results.json`` and
``results.md``: per stiffness the Newton iterations and wall time, every frame certified or not, the largest
stretch after the lower landing (steps 10–78), at the upper landing (steps 79–96) and at the last step, and the
links stretched by more than 1 mm at the end. Needs the Fig. 1 result in ``out/fig01`` (run
``idp run idp/scenes/paper/fig01_dumpling.toml -o out/fig01``) and the paper's data ($IDP_DATA or ../shared/data).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import meshio
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "idp" / "scenes" / "paper" / "fig21_our_dumplings_on_plate.toml"
PLACEMENTS = (1, 5)  # the manifest's second and sixth dumpling: the sixth falls onto the second
STEPS = 96


def two_dumplings(stiffness: float) -> dict:
    """The committed Fig. 21 scene's data cut down to two dumplings, no pusher, glue of ``stiffness``."""
    from idp.scene.load import read_scene_data

    d = read_scene_data(SCENE)
    d["name"] = f"two-dumplings-glue-k{stiffness:g}"
    d["time"]["steps"] = STEPS
    d["objects"] = [o for o in d["objects"] if o["name"] != "pusher"]
    for o in d["objects"]:
        if "instances" in o:
            o["instances"]["transforms"] = [o["instances"]["transforms"][i] for i in PLACEMENTS]
    d["sticky"]["bodies"] = [b for b in d["sticky"]["bodies"] if b != "pusher"]
    d["sticky"]["stiffness"] = float(stiffness)
    return d


def measure(stats: dict, run: Path) -> dict:
    steps = [s for s in stats["steps"] if "sticky" in s]

    def largest(a: int, b: int) -> float:
        return max(s["sticky"]["max_link_stretch"] for s in steps if a <= s["step"] <= b)

    ck = np.load(run / "checkpoint.npz")
    glue = next(k[: -len("rest_lengths")] for k in ck.files if k.endswith("__rest_lengths"))  # the sticky condition's
    pairs, rest = ck[glue + "pairs"], ck[glue + "rest_lengths"]
    last = sorted((run / "vtu").glob("frame_*.vtu"))[-1]
    x = meshio.read(last).points
    stretch = np.abs(np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) - rest)
    return {
        "links": int(pairs.shape[0]),
        "newton_iterations": int(stats["summary"]["newton_iterations"]),
        "stepping_s": float(sum(s.get("wall_time", 0.0) for s in steps)),
        "all_certified": bool(stats["summary"]["all_certified"]),
        "stretch_lower_landed": largest(10, 78),
        "stretch_upper_landing": largest(79, STEPS),
        "stretch_end": float(stretch.max()),
        "links_over_1mm_end": int((stretch > 1e-3).sum()),
    }


def main() -> None:
    from idp.scene.load import dump_scene_toml, scene_from_dict

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--stiffness", type=float, nargs="+", default=[1.0, 10.0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("-o", "--output", default=str(ROOT / "bench" / "results" / "glue_stiffness"))
    a = p.parse_args()
    out = Path(a.output)
    rows = {}
    for k in a.stiffness:
        run = out / f"k{k:g}"
        scene = scene_from_dict(two_dumplings(k), base_dir=SCENE.parent, source=f"{SCENE} (two dumplings, k {k:g})")
        out.mkdir(parents=True, exist_ok=True)
        file = out / f"two_dumplings_k{k:g}.toml"  # mesh paths resolved: runs from anywhere
        file.write_text(dump_scene_toml(scene))
        t = time.perf_counter()
        cmd = [sys.executable, "-m", "idp.cli", "run", str(file), "-o", str(run), "--threads", str(a.threads), "-q"]
        subprocess.run(cmd, check=True)
        wall = time.perf_counter() - t
        rows[f"{k:g}"] = {"wall_s": wall, **measure(json.loads((run / "stats.json").read_text()), run)}
        print(f"k {k:g}: {rows[f'{k:g}']}", flush=True)
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    lines = [
        "| glue stiffness | Newton its | wall (s) | certified | largest stretch, lower landed | at the upper landing"
        " | at step 96 | links > 1 mm at step 96 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, r in rows.items():
        lines.append(
            f"| {k} | {r['newton_iterations']} | {r['wall_s']:.0f} | {r['all_certified']} | "
            f"{r['stretch_lower_landed']:.1e} | {r['stretch_upper_landing']:.1e} | {r['stretch_end']:.1e} | "
            f"{r['links_over_1mm_end']} of {r['links']} |"
        )
    (out / "results.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
