"""Does a handle step cost more than a growth step of the same size? (issue: handles, §4.3 speed target)

Same mesh (the Fig. 10 bar, 7,287 vertices / 27,444 tets), same material, same number of steps, no contact in
reach, three runs:

* ``handles``: both end caps turned by handles (the §4.3 path: feasible move, penalty, held rows);
* ``growth``: the caps pinned (removed from the unknowns) and the rest shape grown by 1 % per step;
* ``growth_held``: the same growth with the caps held by fixed handles, so the system has the handle run's
  unknowns and matrix pattern (held DOFs stay in the pattern as identity rows).

Per-Newton-iteration timings of whole runs mix two things: what the handle path costs, and what the state costs
(the elastic kernel takes its eigen-decomposition path on bent elements, its direct path on uniformly grown
ones). The ``same_state`` part separates them: on one state (the handle run's last, bent, and the rest shape grown
1 %) it times the assembly of both systems (median of interleaved repeats) and the handle path's own pieces
(penalty gradient and diagonal, the held-row scatter).

    .venv/bin/python bench/bench_handles.py -o bench/results/handles [--steps 10] [--repeats 40]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from idp._blas_threads import quiet_blas
from idp.api import simulate
from idp.bench.machine import describe
from idp.bench.scenes import paper_scene
from idp.scene.build import build_scene
from idp.scene.schema import FixedSelector, HandleSpec
from idp.solver.linear import make_linear_solver
from idp.solver.newton import NewtonResult, StepSolver
from idp.stepper.dirichlet import DirichletTargets

KEYS = ["assembly", "linear_solve", "ccd", "line_search", "contact_build", "certificate", "other"]


def _per_iteration(res) -> dict:
    its = max(res.summary["newton_iterations"], 1)
    return {k: v / its for k, v in res.summary["timings"].items()} | {"iterations": its}


def _scenes(steps: int) -> dict:
    handles = paper_scene("fig10_bar_elastic.toml", steps=steps)
    out = {"handles": handles}
    for name in ("growth", "growth_held"):
        scene = paper_scene("fig10_bar_elastic.toml", steps=steps)
        bar = scene.objects[0]
        caps = [h.select for h in bar.handles[:2]]
        if name == "growth":
            bar.fixed = [FixedSelector(box=c.box, relative=True) for c in caps]
            bar.handles = []
        else:
            bar.handles = [
                HandleSpec.model_validate({"name": f"cap{i}", "select": c.model_dump(), "motion": {"type": "fixed"}})
                for i, c in enumerate(caps)
            ]
        bar.rest_shape.growth_rate, bar.rest_shape.growth_steps = 0.01, steps
        out[name] = scene
    return out


def _median_ms(calls: dict, repeats: int) -> dict:
    """Median wall time (ms) of each callable, calls interleaved so drifts of the machine hit all alike."""
    for f in calls.values():
        f()
    times: dict = {k: [] for k in calls}
    for _ in range(repeats):
        for k, f in calls.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    return {k: 1000.0 * float(np.median(v)) for k, v in times.items()}


def _same_state(handles_scene, growth_scene, bent: np.ndarray, repeats: int) -> dict:
    """Assembly (gradient + Hessian into the fixed pattern) of both systems on the same states, and the handle
    path's own additions, in ms."""
    bh, bg = build_scene(handles_scene), build_scene(growth_scene)
    sh, sg = bh.system, bg.system
    solver_h = StepSolver(sh, bh.newton, make_linear_solver("auto", dofs_per_node=3))
    solver_g = StepSolver(sg, bg.newton, make_linear_solver("auto", dofs_per_node=3))
    x0 = sh.x.copy()
    caps = np.flatnonzero(~sg.free_mask.reshape(-1, 3).any(axis=1))  # the growth run pins what the handles move
    out: dict = {
        "unknowns": {"handles": int(sh.dof_map.num_free), "growth": int(sg.dof_map.num_free)},
        "cap_vertices": int(caps.size),
    }
    for state_name, x in (("bent", bent), ("grown_1pct", 1.01 * x0)):
        ev_h, ev_g = solver_h._contact_eval(x, NewtonResult()), solver_g._contact_eval(x, NewtonResult())
        c = sh.step_constraint
        assert isinstance(c, DirichletTargets)
        c.set_targets(caps, x[caps] + 1e-3)
        c.begin(x, lambda x_, P_: 0.5)  # half of the move feasible: penalty on, targets unmet

        def with_penalty(x=x, ev=ev_h, c=c):
            solver_h._constraint = c
            solver_h._derivatives(x, x0, ev)

        def handles_plain(x=x, ev=ev_h):
            solver_h._constraint = None
            solver_h._derivatives(x, x0, ev)

        def growth(x=x, ev=ev_g):
            solver_g._constraint = None
            solver_g._derivatives(x, x0, ev)

        ms = _median_ms({"growth": growth, "handles": handles_plain, "handles_penalty_on": with_penalty}, repeats)
        c._hold()
        solver_h._update_held(c, sh.dof_map.free_dofs)
        _, H = solver_h._derivatives(x, x0, ev_h)

        def hold_first(H=H):
            solver_h._row_cache = None
            solver_h._hold(H)

        ms |= {f"held_rows_{k}": v for k, v in _median_ms({"first": hold_first}, repeats).items()}
        ms["held_rows_cached"] = _median_ms({"cached": lambda H=H: solver_h._hold(H)}, repeats)["cached"]
        out[state_name] = ms
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results/handles"))
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=40, help="interleaved repeats of the same-state timings")
    ap.add_argument(
        "--held-in-matrix",
        action="store_true",
        help="factorise held DOFs as identity rows of the whole matrix, as before idp.solver.held_reduction",
    )
    a = ap.parse_args()
    if a.held_in_matrix:  # the Newton loop's test for the reduction, made to say no
        import idp.solver.newton

        idp.solver.newton.keeps_vertex_groups = lambda held, dofs_per_node: False
    a.output.mkdir(parents=True, exist_ok=True)

    scenes = _scenes(a.steps)
    out: dict = {"machine": describe(), "steps": a.steps}
    bent = np.empty(0)
    for name, scene in scenes.items():
        t = time.perf_counter()
        res = simulate(scene, a.output / name, progress=False)
        out[name] = {"wall": time.perf_counter() - t, "per_iteration": _per_iteration(res)}
        if name == "handles":
            bent = np.load(a.output / name / "checkpoint.npz")["x"]
    with quiet_blas():  # as inside a run (idp._blas_threads)
        out["same_state"] = _same_state(scenes["handles"], scenes["growth"], bent, a.repeats)
    (a.output / "handles_vs_growth.json").write_text(json.dumps(out, indent=2))

    print("| run | Newton its | " + " | ".join(KEYS) + " (ms per iteration) |")
    print("|---|---|" + "---|" * len(KEYS))
    for name in scenes:
        p = out[name]["per_iteration"]
        print(f"| {name} | {p['iterations']} | " + " | ".join(f"{1000 * p.get(k, 0.0):.1f}" for k in KEYS) + " |")
    ss = out["same_state"]
    print(f"\nsame state, assembly (ms, median of {a.repeats}); unknowns {ss['unknowns']}")
    print("| state | growth system | handle system | handle system, penalty on | held rows (first / cached) |")
    print("|---|---|---|---|---|")
    for st in ("bent", "grown_1pct"):
        m = ss[st]
        print(
            f"| {st} | {m['growth']:.2f} | {m['handles']:.2f} | {m['handles_penalty_on']:.2f} | "
            f"{m['held_rows_first']:.3f} / {m['held_rows_cached']:.3f} |"
        )


if __name__ == "__main__":
    main()
