"""`idp bench`: run the §6 suite scene by scene (each in its own process, for a clean peak-memory figure),
write one JSON per scene, a Markdown table beside the reference figures, and PNG plots.

    idp bench --quick -o bench/results/quick      # the tier to run before every performance change
    idp bench -o bench/results/full               # everything
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

from idp.bench.machine import describe, summary
from idp.bench.reference import PAPER, REFERENCE


def _tiny_scene():
    """A generated scene (no data needed) used by the test suite to exercise this code path."""
    from idp.scene.load import scene_from_dict

    return scene_from_dict(
        {
            "name": "tiny",
            "time": {"h": 0.0016, "steps": 3},
            "solver": {"newton_tol": 0.5},
            "contact": {"dhat": 2e-3, "dhat_mode": "relative"},
            "output": {"obj": False, "vtu": False, "png": False},
            "objects": [
                {
                    "name": "ball",
                    "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
                    "rest_shape": {"growth_rate": 0.2, "growth_steps": 3},
                },
                {
                    "name": "box",
                    "kind": "obstacle",
                    "generate": {"shape": "box_surface", "lo": [-0.45] * 3, "hi": [0.45] * 3, "resolution": 2},
                },
            ],
        }
    )


def scene_table() -> dict:
    """name -> (factory, tier); data scenes only when the paper's data is present."""
    from idp.bench.data import find_data_dir
    from idp.bench.scenes import suite

    table = {"tiny": (_tiny_scene, "test")}
    data = find_data_dir()
    if data is not None:
        table.update(suite(data))
    return table


def run_child(name: str, out: Path, steps: int | None) -> dict:
    """Run one scene in this process and write OUT/NAME.json."""
    from idp.api import simulate

    factory, _ = scene_table()[name]
    scene = factory()
    t0 = time.perf_counter()
    res = simulate(scene, out / name, steps=steps, progress=False)
    wall = time.perf_counter() - t0
    recs = res.step_records
    its = [r["newton_iterations"] for r in recs]
    total_its = max(sum(its), 1)
    split = {k: v / total_its for k, v in res.summary["timings"].items()}
    from idp.output.stats import load_stats

    meta = load_stats(out / name / "stats.json")["meta"]
    result = {
        "scene": name,
        "vertices": meta["num_dynamic_vertices"],
        "obstacle_vertices": meta["num_vertices"] - meta["num_dynamic_vertices"],
        "tets": meta["num_elements"],
        "steps": len(recs),
        "wall_total": wall,
        "wall_steps": sum(r["wall_time"] for r in recs),
        "wall_per_step": [r["wall_time"] for r in recs],
        "newton_iterations": sum(its),
        "newton_per_step": its,
        "seconds_per_iteration": sum(r["wall_time"] for r in recs) / total_its,
        "per_iteration_split": split,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "contacts_per_step": [r["contacts"] for r in recs],
        "fill_per_step": [r["fill_fraction"] for r in recs],
        "fill_final": res.summary["fill_fraction"],
        "volume_ratio": (res.summary.get("flow") or {}).get("volume_ratio"),
        "repair": res.summary.get("repair"),  # animation repair: deviation, unchanged frames, crossings left
        "distortion": res.summary.get("distortion"),  # min-max runs: worst / p99 / mean Ψ_SD at the end
        "certified_frames": sum(
            1 for r in recs if r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"]
        ),
        "uncertified_frames": sum(
            1 for r in recs if not (r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"])
        ),
        "nonconverged_steps": res.summary["nonconverged_steps"],
        "linear_solver": meta.get("linear_solver"),
        "machine": describe(),
    }
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    return result


def write_table(results: list[dict], out: Path, machine: dict | None = None) -> str:
    """results.md: the machine (header), the per-scene table, the per-iteration split; returns the text."""
    rows = [
        "| scene | verts / tets | steps | wall, process (s) | ref wall (s) | speed-up | Newton its (ref) "
        "| s / it (ref) | fill, volume or worst Ψ (ref) | peak RSS MB (ref) | certified |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ref = REFERENCE.get(r["scene"], {})
        rw = ref.get("wall")
        wall = r.get("wall_process", r["wall_total"])
        speed = f"{rw / wall:.2f}×" if rw else "–"
        ref_spi = f"{rw / ref['newton_iterations']:.3f}" if rw else "–"
        fill = f"{100 * r['fill_final']:.2f} %" if r["fill_final"] is not None else "–"
        rfill = f"{100 * ref['fill']:.2f} %" if ref.get("fill") is not None else "–"
        if r.get("volume_ratio") is not None:  # flows: enclosed-volume growth instead of a fill fraction
            fill = f"vol ×{r['volume_ratio']:.3f}"
            rfill = f"×{ref['volume_ratio']:.3f}" if ref.get("volume_ratio") else "–"
        if r.get("distortion") and r.get("fill_final") is None:  # min-max runs: the worst element at the end
            fill = f"worst Ψ {r['distortion']['worst']:.3g}"
        rows.append(
            f"| {r['scene']} | {r['vertices']} / {r['tets']} | {r['steps']} | {wall:.1f} | {rw if rw else '–'} "
            f"| {speed} | {r['newton_iterations']} ({ref.get('newton_iterations', '–')}) "
            f"| {r['seconds_per_iteration']:.3f} ({ref_spi}) | {fill} ({rfill}) "
            f"| {r['peak_rss_mb']:.0f} ({ref.get('peak_rss_mb', '–')}) | {r['certified_frames']}/{r['steps']} |"
        )
    split_rows = [
        "",
        "Per Newton iteration (seconds): where the time goes",
        "",
        "| scene | assembly | linear solve | CCD | line search (trial energies) | contact build | certificate | other "
        "| assembly + CCD + contact build |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        s = r["per_iteration_split"]
        rest = s.get("assembly", 0.0) + s.get("ccd", 0.0) + s.get("contact_build", 0.0)
        split_rows.append(
            f"| {r['scene']} | "
            + " | ".join(
                f"{s.get(k, 0.0):.4f}"
                for k in ("assembly", "linear_solve", "ccd", "line_search", "contact_build", "certificate", "other")
            )
            + f" | {rest:.4f} |"
        )
    paper = [
        "",
        "Paper's own figures (§6): "
        + "; ".join(
            f"{k}: {100 * v['fill']:.1f} % fill" + (f" ({v['note']})" if "note" in v else "") for k, v in PAPER.items()
        ),
    ]
    header = summary(machine if machine is not None else describe())
    text = "\n".join(["  \n".join(header), "", *rows, *split_rows, *paper]) + "\n"
    (out / "results.md").write_text(text)
    return text


def write_plots(results: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in results:
        if r["fill_per_step"] and r["fill_per_step"][0] is not None:
            ax.plot(range(1, len(r["fill_per_step"]) + 1), [100 * f for f in r["fill_per_step"]], label=r["scene"])
    ax.set_xlabel("step")
    ax.set_ylabel("fill fraction (%)")
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:  # scenes without a cage (flows, repair, min-max) have no fill curve
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "fill_per_step.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4.5))
    pts = [(r["vertices"], r["seconds_per_iteration"], r["scene"]) for r in results if r["scene"].startswith("bunny")]
    if pts:
        n, t, names = zip(*sorted(pts), strict=True)
        ax.loglog(n, t, "o-", label="idp")
        for ni, ti, nm in pts:
            ax.annotate(nm, (ni, ti), fontsize=7)
        ref = [
            (REFERENCE[nm]["verts"], REFERENCE[nm]["wall"] / REFERENCE[nm]["newton_iterations"])
            for nm in names
            if nm in REFERENCE
        ]
        if ref:
            rn, rt = zip(*ref, strict=True)
            ax.loglog(rn, rt, "s--", label="reference (C++)")
        if len(n) >= 2:
            slope = math.log(t[-1] / t[0]) / math.log(n[-1] / n[0])
            ax.set_title(f"seconds per Newton iteration (idp slope {slope:.2f})")
    ax.set_xlabel("vertices")
    ax.set_ylabel("seconds per Newton iteration")
    ax.grid(alpha=0.3, which="both")
    if pts:
        ax.legend()
    fig.tight_layout()
    fig.savefig(out / "scaling.png", dpi=120)
    plt.close(fig)


def main(args) -> int:
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    table = scene_table()
    if args.only:
        names = args.only
        unknown = [n for n in names if n not in table]
        if unknown:
            print(f"idp bench: unknown or unavailable scene(s) {unknown}; available: {sorted(table)}", file=sys.stderr)
            return 2
    else:
        if len(table) == 1:
            print(
                "idp bench: the paper's data was not found (set IDP_DATA); only the 'tiny' scene is available",
                file=sys.stderr,
            )
            return 2
        tiers = ("quick",) if args.quick else ("quick", "full")
        names = [n for n, (_, tier) in table.items() if tier in tiers]
    results = []
    for name in names:
        print(f"idp bench: {name} ...", flush=True)
        cmd = [sys.executable, "-m", "idp.bench.suite", "--child", name, "-o", str(out)]
        if getattr(args, "steps", None):
            cmd += ["--steps", str(args.steps)]
        t0 = time.perf_counter()
        r = subprocess.run(cmd)
        process_wall = time.perf_counter() - t0
        if r.returncode != 0:
            print(f"idp bench: {name} failed (exit {r.returncode})", file=sys.stderr)
            continue
        res = json.loads((out / f"{name}.json").read_text())
        res["wall_process"] = process_wall  # whole process, start-up and loading included (as the reference's)
        (out / f"{name}.json").write_text(json.dumps(res, indent=1))
        results.append(res)
        fill = "–" if res["fill_final"] is None else f"{100 * res['fill_final']:.2f} %"
        print(
            f"  {res['wall_total']:.1f} s, {res['newton_iterations']} Newton its, fill {fill}, "
            f"{res['certified_frames']}/{res['steps']} frames certified",
            flush=True,
        )
    if results:
        machine = describe()
        print(write_table(results, out, machine))
        write_plots(results, out)
        (out / "suite.json").write_text(json.dumps({"machine": machine, "results": results}, indent=1))
    return 0 if results and all(r["uncertified_frames"] == 0 for r in results) else 1


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--child", required=True)
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--steps", type=int)
    a = p.parse_args()
    run_child(a.child, Path(a.output), a.steps)
