"""`idp bench`: run the §6 suite scene by scene (each in its own process, for a clean peak-memory figure),
write one JSON per scene, a Markdown table and PNG plots.

    idp bench --quick -o bench/results/quick                   # the tier to run before every performance change
    idp bench -o bench/results/full                            # everything
    idp bench --quick --with-reference -o bench/results/ref    # idp and the authors' code in turn, same machine

Speed-ups are reported only from ``--with-reference`` runs (both codes on this machine, alternating); without
it the table gives idp's own figures beside the reference's recorded Newton iterations and fills, which do not
depend on the machine (its runs are deterministic).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from idp.bench.reference import PAPER, REFERENCE
from idp.bench.reference_blas import describe_choice
from idp.bench.reference_run import REFERENCE_CASES, compare, find_reference, run_reference


def _ball_in_box(name: str, growth_rate: float, growth_steps: int, **extra) -> dict:
    """A generated ball growing inside a box (no data needed): the test tier's scenes."""
    return {
        "name": name,
        "time": {"h": 0.0016},
        "solver": {"newton_tol": 0.5},
        "contact": {"dhat": 2e-3, "dhat_mode": "relative"},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [
            {
                "name": "ball",
                "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
                "rest_shape": {"growth_rate": growth_rate, "growth_steps": growth_steps},
            },
            {
                "name": "box",
                "kind": "obstacle",
                "generate": {"shape": "box_surface", "lo": [-0.45] * 3, "hi": [0.45] * 3, "resolution": 2},
            },
        ],
        **extra,
    }


def _tiny_scene():
    """A generated scene (no data needed) used by the test suite to exercise this code path."""
    from idp.scene.load import scene_from_dict

    d = _ball_in_box("tiny", 0.2, 3)
    d["time"]["steps"] = 3
    return scene_from_dict(d)


def _tiny_staged_scene():
    """A generated two-stage scene (grow and bake, then settle) exercising the staged bench record."""
    from idp.scene.load import scene_from_dict

    stages = [{"name": "grow", "steps": 2, "after": {"ball": "bake"}}, {"name": "settle", "steps": 1}]
    return scene_from_dict(_ball_in_box("tiny_stages", 0.1, 2, stages=stages))


def scene_table() -> dict:
    """name -> (factory, tier); data scenes only when the paper's data is present."""
    from idp.bench.data import find_data_dir
    from idp.bench.scenes import suite

    table = {"tiny": (_tiny_scene, "test"), "tiny_stages": (_tiny_staged_scene, "test")}
    data = find_data_dir()
    if data is not None:
        table.update(suite(data))
    return table


def parse_solver_overrides(items: list[str] | None) -> dict:
    """``KEY=VALUE`` strings (``--solver``) → a dict of ``[solver]`` settings, each value read as a TOML value
    (``3``, ``1e-2``, ``true``, ``"scipy"``; a bare word is taken as a string) and the whole checked against the
    scene schema's solver table now, so a wrong key or value stops the bench before any run."""
    from idp.errors import SceneError
    from idp.scene.load import tomllib  # tomli before Python 3.11
    from idp.scene.schema import SolverConfig

    out: dict = {}
    for item in items or []:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SceneError(f"--solver {item!r}: expected KEY=VALUE, e.g. contact_lookahead=3")
        try:
            out[key] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = raw.strip()
    if out:
        try:
            SolverConfig.model_validate(out)
        except ValueError as exc:
            raise SceneError(f"--solver: {exc}") from None
    return out


def _with_solver(scene, overrides: dict):
    """``scene`` with its ``[solver]`` settings updated by ``overrides`` (validated as a whole)."""
    if not overrides:
        return scene
    from idp.scene.schema import SolverConfig

    solver = SolverConfig.model_validate({**scene.solver.model_dump(exclude_unset=True), **overrides})
    return scene.model_copy(update={"solver": solver})


def run_child(name: str, out: Path, steps: int | None, freeze: bool = False, solver: dict | None = None) -> dict:
    """Run one scene in this process and write OUT/NAME.json. ``freeze``: the process runs only this scene
    (the bench's child), so the imported modules are frozen for the collector first, as `idp run` does.
    ``solver``: ``[solver]`` settings that replace the scene's (``idp bench --solver``)."""
    from idp.api import simulate

    factory, _ = scene_table()[name]
    scene = _with_solver(factory(), solver or {})
    if freeze:
        from idp._heap import freeze_startup_heap

        freeze_startup_heap()  # as `idp run` does
    t0 = time.perf_counter()
    res = simulate(scene, out / name, steps=steps, progress=False)
    wall = time.perf_counter() - t0
    if scene.stages:  # a modeling scene: one run per stage, summed
        return _staged_result(name, out, res, wall)
    recs = res.step_records
    from idp.output.stats import load_stats

    meta = load_stats(out / name / "stats.json")["meta"]
    result = {
        "scene": name,
        "vertices": meta["num_dynamic_vertices"],
        "obstacle_vertices": meta["num_vertices"] - meta["num_dynamic_vertices"],
        "tets": meta["num_elements"],
        **_step_figures(recs, wall, res.summary["timings"]),
        "fill_per_step": [r["fill_fraction"] for r in recs],
        "fill_final": res.summary["fill_fraction"],
        "volume_ratio": (res.summary.get("flow") or {}).get("volume_ratio"),
        "repair": res.summary.get("repair"),  # animation repair: deviation, unchanged frames, crossings left
        "distortion": res.summary.get("distortion"),  # min-max runs: worst / p99 / mean Ψ_SD at the end
        "nonconverged_steps": res.summary["nonconverged_steps"],
        "linear_solver": meta.get("linear_solver"),
        "cage_volume": meta.get("cage_volume"),
        "solver_overrides": solver or None,
    }
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    return result


def _step_figures(recs: list[dict], wall: float, timings: dict[str, float]) -> dict:
    """The per-step figures of a bench record (steps, times, Newton iterations, contacts, certified frames) and
    the per-iteration split of ``timings`` (seconds summed over the steps)."""
    its = [r["newton_iterations"] for r in recs]
    total_its = max(sum(its), 1)
    certified = [r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"] for r in recs]
    return {
        "steps": len(recs),
        "wall_total": wall,
        "wall_steps": sum(r["wall_time"] for r in recs),
        "wall_per_step": [r["wall_time"] for r in recs],
        "newton_iterations": sum(its),
        "newton_per_step": its,
        "seconds_per_iteration": sum(r["wall_time"] for r in recs) / total_its,
        "per_iteration_split": {k: v / total_its for k, v in timings.items()},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "contacts_per_step": [r["contacts"] for r in recs],
        "certified_frames": sum(certified),
        "uncertified_frames": len(certified) - sum(certified),
    }


def _staged_result(name: str, out: Path, res, wall: float) -> dict:
    """The bench record of a multi-stage scene (paper §7.5): every stage's steps in order, element counts per stage
    (a remesh between stages changes them), the figures summed over the stages."""
    from idp.output.stats import load_stats

    recs: list[dict] = []
    per_stage = []
    timings: dict[str, float] = {}
    for stage in res.stages:
        sdir = out / name / "stages" / f"{stage['index']:02d}_{stage['stage']}"
        stats = load_stats(sdir / "stats.json")
        steps = [r for r in stats["steps"] if not r.get("initial")]
        recs += steps
        for k, v in stats["summary"].get("timings", {}).items():
            timings[k] = timings.get(k, 0.0) + float(v)
        per_stage.append(
            {
                "stage": stage["stage"],
                "steps": len(steps),
                "wall_time": stage["wall_time"],
                "newton_iterations": stage["newton_iterations"],
                "vertices": stats["meta"]["num_dynamic_vertices"],
                "tets": stats["meta"]["num_elements"],
                "remesh": {k: v.get("remesh") for k, v in (stage.get("objects") or {}).items() if v.get("remesh")},
            }
        )
    result = {
        "scene": name,
        "vertices": max(p["vertices"] for p in per_stage),
        "tets": max(p["tets"] for p in per_stage),
        "stages": per_stage,
        **_step_figures(recs, wall, timings),
        "fill_per_step": [None] * len(recs),
        "fill_final": None,
        "nonconverged_steps": res.summary["nonconverged_steps"],
    }
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    return result


def describe() -> dict:
    """The machine this process runs on (:func:`idp.bench.machine.describe`, imported when first needed)."""
    from idp.bench.machine import describe as machine

    return machine()


def write_table(results: list[dict], out: Path, machine: dict | None = None, compared: dict | None = None) -> str:
    """results.md: the machine (header), the same-run comparison with the reference (when run), idp's per-scene
    table, the per-iteration split of both codes; returns the text."""
    compared = compared or {}
    same_run = _same_run_rows(results, compared) if compared else []
    rows = [
        "",
        "idp per scene (Newton iterations and fill beside the reference's recorded ones, which do not depend on "
        "the machine; speed-ups only from the same-run table)",
        "",
        "| scene | verts / tets | steps | wall, process (s) | Newton its (ref) | s / it "
        "| fill, volume or worst Ψ (ref) | peak RSS MB | certified |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ref = REFERENCE.get(r["scene"], {})
        wall = r.get("wall_process", r["wall_total"])
        fill = f"{100 * r['fill_final']:.2f} %" if r["fill_final"] is not None else "–"
        rfill = f"{100 * ref['fill']:.2f} %" if ref.get("fill") is not None else "–"
        if r.get("volume_ratio") is not None:  # flows: enclosed-volume growth instead of a fill fraction
            fill = f"vol ×{r['volume_ratio']:.3f}"
            rfill = f"×{ref['volume_ratio']:.3f}" if ref.get("volume_ratio") else "–"
        if r.get("distortion") and r.get("fill_final") is None:  # min-max runs: the worst element at the end
            fill = f"worst Ψ {r['distortion']['worst']:.3g}"
        rows.append(
            f"| {r['scene']} | {r['vertices']} / {r['tets']} | {r['steps']} | {wall:.1f} "
            f"| {r['newton_iterations']} ({ref.get('newton_iterations', '–')}) "
            f"| {r['seconds_per_iteration']:.3f} | {fill} ({rfill}) "
            f"| {r['peak_rss_mb']:.0f} | {r['certified_frames']}/{r['steps']} |"
        )
    keys = ("assembly", "linear_solve", "ccd", "line_search", "contact_build", "certificate", "other")
    split_rows = [
        "",
        "Per Newton iteration (seconds): where the time goes"
        + (" (reference rows: its own timing tree, grouped as listed in docs/benchmarks.md)" if compared else ""),
        "",
        "| scene | code | assembly | linear solve | CCD | line search (trial energies) | contact build | certificate "
        "| other | all but the solve |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ref_split = compared.get(r["scene"], {}).get("reference_split")
        for code, s in (("idp", r["per_iteration_split"]), ("reference", ref_split)):
            if not s:
                continue
            rest = sum(v for k, v in s.items() if k not in ("linear_solve", "outside_solver"))
            cells = " | ".join("–" if k not in s else f"{s[k]:.4f}" for k in keys)
            split_rows.append(f"| {r['scene']} | {code} | {cells} | {rest:.4f} |")
    paper = [
        "",
        "Paper's own figures (§6): "
        + "; ".join(
            f"{k}: {100 * v['fill']:.1f} % fill" + (f" ({v['note']})" if "note" in v else "") for k, v in PAPER.items()
        ),
    ]
    from idp.bench.machine import summary

    header = summary(machine if machine is not None else describe())
    text = "\n".join(["  \n".join(header), *same_run, *rows, *split_rows, *paper]) + "\n"
    (out / "results.md").write_text(text)
    return text


def _same_run_rows(results: list[dict], compared: dict) -> list[str]:
    """The same-run table: idp and the reference alternating on this machine, medians and per-run ratios."""
    rows = [
        "",
        "Same machine, same run: idp and the authors' reference code alternating (whole process wall, medians)",
        "",
        "| scene | runs | idp wall (s) | reference wall (s) | speed-up (per run) | Newton its idp / ref "
        "| fill idp / ref | peak RSS MB idp / ref |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        c = compared.get(r["scene"])
        if c is None:
            continue
        if "unavailable" in c:
            rows.append(
                f"| {r['scene']} | – | {r.get('wall_process', r['wall_total']):.1f} | – | {c['unavailable']} "
                "| – | – | – |"
            )
            continue
        per_run = ", ".join(f"{x:.2f}" for x in c["speedup_per_run"])
        fills = "–" if c["idp_fill"] is None else f"{100 * c['idp_fill']:.2f} %"
        rfill = "–" if c["reference_fill"] is None else f"{100 * c['reference_fill']:.2f} %"
        rows.append(
            f"| {r['scene']} | {c['runs']} | {c['idp_wall_median']:.1f} | {c['reference_wall_median']:.1f} "
            f"| **{c['speedup']:.2f}×** ({per_run}) "
            f"| {c['idp_newton_iterations']} / {c['reference_newton_iterations']} "
            f"| {fills} / {rfill} | {c['idp_peak_rss_mb']:.0f} / {c['reference_peak_rss_mb']:.0f} |"
        )
    choices = {describe_choice(c["reference_blas"]) for c in compared.values() if c.get("reference_blas")}
    if choices:
        rows += ["", "BLAS: " + "; ".join(sorted(choices)) + " (idp/bench/reference_blas.py)"]
    return rows


def write_plots(results: list[dict], out: Path, compared: dict | None = None) -> None:
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
        same_run = {k: c for k, c in (compared or {}).items() if "unavailable" not in c}
        ref = [
            (n_, same_run[nm]["reference_wall_median"] / same_run[nm]["reference_newton_iterations"])
            for n_, nm in zip(n, names, strict=True)
            if nm in same_run
        ]
        if ref:  # only from the same run (a time taken on another machine is not comparable)
            rn, rt = zip(*ref, strict=True)
            ax.loglog(rn, rt, "s--", label="reference (C++), same run")
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


def _run_idp(name: str, out: Path, steps: int | None, solver: list[str] | None = None) -> dict | None:
    """One idp run of a suite scene in its own process; the child's JSON plus the whole-process wall."""
    cmd = [sys.executable, "-m", "idp.bench.suite", "--child", name, "-o", str(out)]
    if steps:
        cmd += ["--steps", str(steps)]
    for item in solver or []:
        cmd += ["--solver", item]
    t0 = time.perf_counter()
    r = subprocess.run(cmd)
    process_wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(f"idp bench: {name} failed (exit {r.returncode})", file=sys.stderr)
        return None
    res = json.loads((out / f"{name}.json").read_text())
    res["wall_process"] = process_wall  # whole process, start-up and loading included (as the reference's)
    # described here, not in the child: importing the description's tools and reading the machine took ≈ 70 ms of
    # the child's wall, which an `idp run` does not spend
    res["machine"] = describe()
    (out / f"{name}.json").write_text(json.dumps(res, indent=1))
    return res


def _print_idp(res: dict) -> None:
    fill = "–" if res["fill_final"] is None else f"{100 * res['fill_final']:.2f} %"
    print(
        f"  idp: {res['wall_process']:.1f} s, {res['newton_iterations']} Newton its, fill {fill}, "
        f"{res['certified_frames']}/{res['steps']} frames certified",
        flush=True,
    )


def _run_pairs(name: str, out: Path, runs: int, reference: Path | None, args) -> tuple[list[dict], dict | None]:
    """``runs`` idp runs of one scene, alternating with reference runs when asked; (idp runs, comparison)."""
    from idp.bench.data import find_data_dir

    case = REFERENCE_CASES.get(name) if args.with_reference else None
    unavailable = None
    if args.with_reference and case is None:
        unavailable = "no reference counterpart"
    elif args.with_reference and reference is None:
        unavailable = "reference not found (IDP_REFERENCE)"
    elif args.with_reference and args.steps:
        unavailable = "--steps changes idp's run only"
    idp_runs: list[dict] = []
    ref_runs: list[dict] = []
    for i in range(runs):
        res = _run_idp(name, out, args.steps, getattr(args, "solver", None))
        if res is None:
            break
        idp_runs.append(res)
        _print_idp(res)
        if unavailable is None and case is not None and reference is not None:
            work = out / "reference" / name / f"run{i + 1}"
            try:
                ref = run_reference(
                    reference,
                    case,
                    work,
                    find_data_dir(),
                    timeout=args.reference_timeout,
                    blas=getattr(args, "reference_blas", "auto"),
                )
            except (RuntimeError, ValueError, subprocess.TimeoutExpired) as exc:
                print(f"idp bench: {exc}", file=sys.stderr)
                unavailable = "reference run failed (see stderr)"
                continue
            ref_runs.append(ref)
            print(
                f"  reference ({case.command}): {float(ref['wall_s']):.1f} s, {ref['newton_its']} Newton its, "
                f"peak {float(ref['peak_rss_mb']):.0f} MB; {describe_choice(ref.get('blas'))}",
                flush=True,
            )
    if not idp_runs:
        return [], None
    if not args.with_reference:
        return idp_runs, None
    if unavailable is not None or not ref_runs:
        return idp_runs, {"unavailable": unavailable or "no reference run finished"}
    comparison = compare(idp_runs, ref_runs, idp_runs[-1].get("cage_volume"))
    comparison["reference_command"] = case.command if case else None
    comparison["reference_note"] = case.note if case else ""
    comparison["reference_runs"] = ref_runs
    (out / f"{name}.reference.json").write_text(json.dumps(comparison, indent=1))
    print(f"  speed-up {comparison['speedup']:.2f}× (median of {comparison['runs']})", flush=True)
    return idp_runs, comparison


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
    runs = args.runs or (1 if args.quick or not args.with_reference else 2)
    from idp.errors import SceneError

    try:
        overrides = parse_solver_overrides(getattr(args, "solver", None))
    except SceneError as exc:
        print(f"idp bench: {exc}", file=sys.stderr)
        return 2
    if overrides:
        print(f"idp bench: every idp run with [solver] {overrides}", flush=True)
    from idp._bytecode import compile_package

    compile_package()  # each run's process then imports idp as an installed wheel would (idp/_bytecode.py)
    reference = None
    if args.with_reference:
        from idp.bench.data import find_data_dir

        reference = find_reference(find_data_dir())
        if reference is None:
            print(
                "idp bench: the authors' reference code was not found (set IDP_REFERENCE to the folder with "
                "run.sh); idp runs alone and the speed-up is reported as unavailable",
                file=sys.stderr,
            )
        else:
            print(f"idp bench: reference {reference}, {runs} run(s) of each code per scene, alternating", flush=True)
    results, compared = [], {}
    for name in names:
        print(f"idp bench: {name} ...", flush=True)
        idp_runs, comparison = _run_pairs(name, out, runs, reference, args)
        if not idp_runs:
            continue
        res = dict(idp_runs[-1])
        if len(idp_runs) > 1:  # the table shows the median run's wall; every run's wall is kept
            res["wall_process_runs"] = [r["wall_process"] for r in idp_runs]
            res["wall_process"] = statistics.median(res["wall_process_runs"])
        results.append(res)
        if comparison is not None:
            compared[name] = comparison
    if results:
        machine = describe()
        print(write_table(results, out, machine, compared))
        write_plots(results, out, compared)
        summary = {"machine": machine, "results": results, "with_reference": compared or None}
        summary["solver_overrides"] = overrides or None
        (out / "suite.json").write_text(json.dumps(summary, indent=1))
    return 0 if results and all(r["uncertified_frames"] == 0 for r in results) else 1


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--child", required=True)
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--steps", type=int)
    p.add_argument("--solver", action="append")
    a = p.parse_args()
    from idp._heap import freeze_heap_at_exit

    freeze_heap_at_exit()  # as the CLI does: the whole-process wall time is what `idp run` would take
    run_child(a.child, Path(a.output), a.steps, freeze=True, solver=parse_solver_overrides(a.solver))
