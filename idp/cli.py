"""Command line: ``idp run``, ``idp flow``, ``idp font``, ``idp repair``, ``idp uv``, ``idp check``, ``idp demo``,
``idp bench``, ``idp batch``."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from pathlib import Path

EXIT_INPUT, EXIT_CERTIFICATE, EXIT_SOLVER, EXIT_INTERRUPTED = 2, 3, 4, 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a shell reports a command whose reader went away


def _thread_count(text: str) -> int:
    """``--threads N``: 1 to the machine's CPU count. (0 or less made numba refuse to start in the next process
    that read the environment; 10^5 threads crashed it.)"""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    cpus = os.cpu_count() or 1
    if not 1 <= n <= cpus:
        raise argparse.ArgumentTypeError(f"must be between 1 and {cpus} (the CPUs of this machine), got {n}")
    return n


def _set_threads(n: int | None) -> None:
    """Thread count for numba kernels, ipctk (TBB), BLAS and CHOLMOD's routed BLAS (its pool follows numba's count).

    The environment variables reach libraries that load later (and child processes). numba and the OpenBLAS pools
    read their counts when they load, so where a caller loaded them before ``main`` (a script that imports numpy,
    scipy or numba first) they are set directly too; before, such a caller's ``--threads 1`` left numba and
    CHOLMOD's BLAS on every core.

    Once numba's pool has started in this process its size is fixed, and numba re-reads ``NUMBA_NUM_THREADS`` from
    the environment at every compile: a different value there made the next kernel compiled in the process fail
    ("Cannot set NUMBA_NUM_THREADS to a different value once the threads have been launched"; a second ``main``
    call with another ``--threads`` in one process, on a cold kernel cache). So that variable is left as it is then,
    and the count applies through :func:`numba.set_num_threads` (at most the pool's size).
    Where numba was imported but its pool not started, its configuration is re-read before the count is applied,
    so the pool starts at the new size."""
    if not n:
        return
    pool_started = bool(getattr(sys.modules.get("numba.np.ufunc.parallel"), "_is_initialized", False))
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        if var == "NUMBA_NUM_THREADS" and pool_started:
            continue
        os.environ[var] = str(n)
    import ipctk

    ipctk.set_num_threads(n)
    if "numba" in sys.modules:
        import numba

        if not pool_started:
            # numba read NUMBA_NUM_THREADS when it was imported; without a re-read, set_num_threads below starts
            # the pool at that size, and the next kernel compiled in the process (a cold cache) fails on the
            # variable just set
            numba.core.config.reload_config()
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n)  # every BLAS/OpenMP pool loaded so far, for the rest of the process


class Terminated(KeyboardInterrupt):
    """SIGTERM (a job scheduler, ``kill``, a container stop): handled exactly like Ctrl-C — the step under way
    is dropped, everything finished stays on disk, exit code 130, and ``--resume`` goes on."""


def _on_signal(exc: KeyboardInterrupt, what: str) -> None:
    """Inside a run: recorded, raised at the next step or Newton iteration (:mod:`idp.interrupts`); in a
    batch's job loop: raised at once (the batch stops its jobs). Elsewhere (reading the scene, compiling kernels):
    the process ends at once with exit 130 — nothing finished can be lost there (output is written atomically, as
    for a kill), and an exception raised inside an import or numba's glue would surface as an unrelated error."""
    from idp import interrupts

    if interrupts.handled():
        interrupts.request(exc)
        return
    os.write(2, f"idp: {what}; finished steps are on disk (resume with --resume)\n".encode())
    os._exit(EXIT_INTERRUPTED)


def _on_sigterm(signum: int, frame: object) -> None:
    _on_signal(Terminated(), "terminated (SIGTERM)")


def _on_sigint(signum: int, frame: object) -> None:
    _on_signal(KeyboardInterrupt(), "interrupted")


def demo_scene_path() -> Path:
    return Path(__file__).parent / "scenes" / "demo_hourglass.toml"


def _memory_size(text: str) -> int:
    """``--max-memory 4G``: bytes, with K/M/G/T suffixes (powers of 1024)."""
    from idp.solver.memory import parse_memory_size

    try:
        return parse_memory_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positive_seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number of seconds: {text!r}") from None
    if not (v > 0 and v != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds > 0, got {text}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _with_solver_limits(scene, args):
    """The scene with ``--max-memory``, ``--max-step-seconds`` and ``--max-newton-iterations`` put into its
    ``[solver]`` section (a staged scene hands them to every stage)."""
    update = {
        key: value
        for key, value in (
            ("max_memory", args.max_memory),
            ("max_step_seconds", args.max_step_seconds),
            ("max_newton_iterations", args.max_newton_iterations),
        )
        if value is not None
    }
    if update:
        scene.solver = scene.solver.model_copy(update=update)
    return scene


def _cmd_run(args) -> int:
    _set_threads(args.threads)
    from idp._heap import freeze_startup_heap
    from idp.api import simulate
    from idp.scene.load import load_scene

    scene = _with_solver_limits(load_scene(args.scene), args)
    out = args.output or scene.output.dir
    freeze_startup_heap()  # one run per process: its collections need not walk the imported modules (idp._heap)
    result = simulate(
        scene,
        out,
        steps=args.steps,
        progress=not args.quiet,
        resume=args.resume,
        force_resume=args.force,
        check_every_iterate=True if args.check_iterates else None,
        stop_after=args.stop_after,
    )
    return _finish(result, Path(out))


def _cmd_flow(args) -> int:
    _set_threads(args.threads)
    from idp.applications.normal_flow import flow_scene, run_flow

    out = Path(args.output)
    scene = flow_scene(
        args.mesh,
        beta=args.beta,
        gamma=args.smoothing,
        steps=args.steps,
        dhat=args.dhat,
        laplacian=args.laplacian,
        normals=args.normals,
        recompute=args.recompute,
        fix_boundary=not args.free_boundary,
        preserve_input_intersections=args.preserve_intersections,
        newton_tol=args.newton_tol,
        output_dir=out,
    )
    result = run_flow(scene, out, progress=not args.quiet, resume=args.resume, force_resume=args.force)
    return _finish(result, out)


def _cmd_font(args) -> int:
    _set_threads(args.threads)
    from idp.applications.inflated_text import text_flow_scene
    from idp.applications.normal_flow import run_flow

    out = Path(args.output)
    scene = text_flow_scene(
        args.text,
        out,
        font=args.font,
        height=args.height,
        edge_length=args.edge_length,
        beta=args.beta,
        gamma=args.smoothing,
        steps=args.steps,
        dhat=args.dhat,
    )
    result = run_flow(scene, out, progress=not args.quiet, resume=args.resume, force_resume=args.force)
    return _finish(result, out)


def _cmd_repair(args) -> int:
    _set_threads(args.threads)
    from idp.applications.repair import parse_frames, parse_selection, repair_scene, run_repair

    out = Path(args.output)
    start, stop = parse_frames(args.frames) if args.frames else (0, None)
    scene = repair_scene(
        args.input,
        dhat=args.dhat,
        prescribed=[parse_selection(t) for t in args.fixed or []],
        start=start,
        stop=stop,
        first_frame=args.first_frame,
        output=args.format,
        usd_prim=args.usd_prim,
        youngs_modulus=args.youngs_modulus,
        thickness=args.thickness,
        bending=args.bending,
        newton_tol=args.newton_tol,
        kappa_b=args.kappa_b,
        prescribed_contact="guarded" if args.guard_fixed else "follow_input",
    )
    result = run_repair(scene, out, progress=not args.quiet, resume=args.resume, force_resume=args.force)
    return _finish(result, out)


def _cmd_uv(args) -> int:
    _set_threads(args.threads)
    from idp.applications.uv_map import default_report_dir, run_uv, uv_scene

    scene = uv_scene(  # the scene schema checks --p (power >= 1), --steps, --dhat, ... and names the key
        args.input,
        p=args.p,
        steps=args.steps,
        dhat=args.dhat,
        youngs_modulus=args.youngs_modulus,
        newton_tol=args.newton_tol,
        preserve_overlaps=args.preserve_overlaps,
    )
    out = Path(args.output)
    result, report = run_uv(
        scene,
        out,
        report_dir=args.report,
        overwrite=args.overwrite,
        progress=not args.quiet,
        resume=args.resume,
        force_resume=args.force,
    )
    b, a = report["before"], report["after"]
    print(
        f"distortion (SD, 4 = isometric):  worst {b['worst']:.4g} -> {a['worst']:.4g}, "
        f"p99 {b['p99']:.4g} -> {a['p99']:.4g}, mean {b['mean']:.4g} -> {a['mean']:.4g}"
    )
    print(f"flipped UV triangles after:      {report['flipped_after']}")
    print(f"overlapping UV pairs after:      {report['overlapping_pairs_after']}")
    print(f"written:                         {out} (only vt lines changed)")
    code = _finish(result, Path(args.report) if args.report else default_report_dir(out))
    if report["flipped_after"] or report["overlapping_pairs_after"] > report["overlapping_pairs_before"]:
        return EXIT_CERTIFICATE
    return code


def _finish(result, out: Path) -> int:
    """Print the run's summary; exit code 0 when every frame is certified."""
    _print_summary(result, out)
    return 0 if result.summary["all_certified"] else EXIT_CERTIFICATE


def _print_summary(result, out: Path) -> None:
    s = result.summary
    fill = s.get("fill_fraction")
    lines = [
        f"steps run:          {s['steps_run']} ({s['stopped']})",
        f"wall time:          {s['wall_time']:.1f} s",
        f"Newton iterations:  {s['newton_iterations']} ({s['nonconverged_steps']} step(s) not converged)",
        "certificate:        "
        + ("all frames certified" if s["all_certified"] else f"{s['uncertified_frames']} frame(s) FAILED")
        + f" (min surface distance {s['min_distance']:.3e})",
    ]
    if fill is not None:
        lines.insert(
            0,
            f"fill fraction:      {100 * fill:.2f} % of the cage volume"
            f" (start {100 * s['initial_fill_fraction']:.2f} %)",
        )
    for st in s.get("per_stage", []):  # a staged modeling scene: one line per stage
        lines.append(
            f"stage {st['index']} {st['stage']}: {st['steps']} step(s), {st['wall_time']:.1f} s, "
            f"{st['newton_iterations']} Newton iterations, {st['num_elements']} elements"
        )
    rep = s.get("repair")
    if rep:
        crossing = rep.get("frames_with_output_crossings", 0)
        outside = rep.get("frames_with_output_crossings_outside_prescribed", crossing)
        lines.insert(
            0,
            f"repaired frames:    {rep.get('frames')} ({rep.get('unchanged_frames')} unchanged bit for bit); "
            f"max deviation {rep.get('max_deviation', 0.0):.4g}, frames with new crossings: {outside}"
            + (f" (prescribed parts crossing as in the input: {crossing} frames)" if crossing > outside else ""),
        )
    flow = s.get("flow")
    if flow:
        what = "enclosed volume" if flow.get("volume") is not None else "area"
        ratio = flow["volume_ratio"] if flow.get("volume") is not None else flow["area_ratio"]
        value = flow["volume"] if flow.get("volume") is not None else flow["area"]
        lines.insert(0, f"{what + ':':<20}{value:.5g} (x{ratio:.3f} of the input)")
    if s.get("dhat") is not None:
        lines.append(f"contact distance:   d̂ = {s['dhat']:.4g} (absolute)")
    if s.get("steps_with_unmet_targets"):
        lines.append(
            f"handles:            {s['steps_with_unmet_targets']} step(s) ended with targets unmet (stats.json)"
        )
    if s.get("repaired_sequence"):
        lines.append(f"output:             {s['repaired_sequence']} (report.md, report.json, stats.json in {out}/)")
    else:
        names: tuple[str, ...] = ("obj", "vtu", "frames.pvd", "stats.json", "frames.png", "report.md")
        names += ("report.json", "distortion.png", "stages", "stages.json", "final")  # the last three: staged
        present = [n + ("/" if (out / n).is_dir() else "") for n in names if (out / n).exists()]
        lines.append(f"output:             {out}/ ({', '.join(present)})")
    print("\n".join(lines))


def _cmd_check(args) -> int:
    from idp.mesh.checks import check_mesh

    bad = 0
    for path in args.meshes:
        try:
            report = check_mesh(path)
        except Exception as exc:  # report every file, keep going
            from idp.errors import IdpError

            if not isinstance(exc, IdpError):
                raise
            print(f"{path}: ERROR: {exc}")
            bad += 1
            continue
        print(report.format())
        bad += 0 if report.ok else 1
    return 0 if bad == 0 else 1


def _cmd_render(args) -> int:
    from idp.output.run_render import render_run

    run = Path(args.run)
    dim, up = args.dim, args.up
    resolved = run / "scene.resolved.toml"
    if resolved.is_file() and (dim is None or up is None):
        # the run's own scene says how to draw it: read as data only (a stage's scene names files relative to
        # where the run was started, and the picture needs none of them)
        from idp.scene.load import tomllib  # tomli before Python 3.11

        try:
            raw = tomllib.loads(resolved.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            raw = {}
        scene_dim = raw.get("dim") if raw.get("dim") in (2, 3) else 3
        dim = scene_dim if dim is None else dim
        if up is None:
            from idp.output.up_axis import up_axis

            try:
                up = up_axis(dim, str((raw.get("output") or {}).get("up", "auto")), raw.get("gravity"))
            except (TypeError, ValueError):  # a hand-edited scene: draw with z up
                up = "z"
    out = render_run(
        run,
        args.output or run / "render.png",
        dim=dim or 3,
        steps=args.steps,
        views=args.views,
        up=up or "z",
        hide_obstacles=args.hide_obstacles,
    )
    print(out)
    return 0


def _cmd_demo(args) -> int:
    _set_threads(args.threads)
    from idp._heap import freeze_startup_heap
    from idp.api import simulate
    from idp.scene.load import load_scene

    scene = load_scene(demo_scene_path())
    out = Path(args.output)
    freeze_startup_heap()  # one run per process (idp._heap)
    result = simulate(scene, out, steps=args.steps, progress=not args.quiet)
    return _finish(result, out)


def _non_negative_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {n}")
    return n


def _cmd_batch(args) -> int:
    from idp.applications.batch import run_batch

    out = Path(args.output) if args.output else Path("out") / Path(args.spec).stem
    result = run_batch(
        args.spec,
        out,
        scheduler=args.scheduler,
        workers=args.workers,
        threads_per_job=args.threads_per_job,
        retries=args.retries,
        resume=args.resume,
        serial=args.serial,
        progress=not args.quiet,
        dashboard=args.dashboard,
    )
    rows = result.rows
    ok = sum(r["status"] == "ok" for r in rows)
    skipped = f" ({len(result.skipped)} finished earlier, skipped)" if result.skipped else ""
    print(f"jobs:     {len(rows)}: {ok} ok, {len(rows) - ok} failed{skipped}")
    print(f"time:     {result.wall_time:.1f} s on {result.cluster}")
    for r in result.failed:
        print(f"FAILED:   {r['job']} after {r['attempts']} attempt(s): {r['error']}")
    others = ", ".join(t.name for t in result.tables if t.name != "results.md")
    print(f"results:  {result.out / 'results.md'} ({others}, batch.json; each job in {result.out / 'jobs'}/)")
    if result.ok:
        return 0
    # a job whose frames failed the injectivity check outranks any other failure
    return EXIT_CERTIFICATE if any(r.get("exit_code") == EXIT_CERTIFICATE for r in result.failed) else EXIT_SOLVER


def _cmd_bench(args) -> int:
    _set_threads(args.threads)
    from idp.bench.suite import main as bench_main

    return bench_main(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="idp", description="Guaranteed globally injective deformation processing (IDP).")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a scene file (TOML or JSON)")
    r.add_argument("scene", help="scene file")
    r.add_argument("-o", "--output", help="output folder (default: the scene's output.dir)")
    r.add_argument("--steps", type=int, help="override time.steps")
    r.add_argument("--threads", type=_thread_count, help="threads for kernels, contact and BLAS")
    r.add_argument("--resume", action="store_true", help="continue an interrupted run from its checkpoint")
    r.add_argument("--force", action="store_true", help="with --resume: go on even though the scene changed")
    r.add_argument("--check-iterates", action="store_true", help="certify every Newton iterate, not only every frame")
    r.add_argument(
        "--stop-after",
        metavar="STAGE",
        help="staged scenes: stop after this stage (its name, or its index as in OUT/stages/NN_name); "
        "--resume goes on from there",
    )
    r.add_argument(
        "--max-memory",
        type=_memory_size,
        metavar="SIZE",
        help="memory a step may use, e.g. 4G (K/M/G/T: powers of 1024; overrides solver.max_memory); a step "
        "estimated to need more stops before factorising",
    )
    r.add_argument(
        "--max-step-seconds",
        type=_positive_seconds,
        metavar="S",
        help="wall-clock limit per step (overrides solver.max_step_seconds); the step ends after the iterate "
        "that passes it, reported as not converged",
    )
    r.add_argument(
        "--max-newton-iterations",
        type=_positive_int,
        metavar="N",
        help="Newton iteration cap per step (overrides solver.max_newton_iterations)",
    )
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_run)

    f = sub.add_parser("flow", help="globally injective normal flow of a triangle surface (paper §7.2)")
    f.add_argument("mesh", help="triangle surface (OBJ, PLY, STL, ...; or data:flow/cat.obj)")
    f.add_argument("--beta", type=float, default=5e-3, help="flow speed per step: > 0 outward, < 0 inward")
    f.add_argument("--smoothing", type=float, default=0.5, help="smoothing gamma >= 0 (the authors' smoothIntensity)")
    f.add_argument("--steps", type=int, default=10)
    f.add_argument("--dhat", type=float, default=1e-3, help="contact distance (absolute)")
    f.add_argument("--laplacian", choices=["area", "cotangent"], default="area")
    f.add_argument(
        "--normals",
        choices=["mass", "lumped_unit", "area"],
        default="mass",
        help="push weighting: mass (beta per step everywhere), lumped_unit (the authors': current areas), area",
    )
    f.add_argument("--newton-tol", type=float, help="RMS Newton step per vertex to stop at (default 0.05 |beta|)")
    f.add_argument("--recompute", choices=["auto", "always", "never"], default="auto", help="rebuild M and L per step")
    f.add_argument("--free-boundary", action="store_true", help="let the boundary of an open surface move")
    f.add_argument(
        "--preserve-intersections",
        action="store_true",
        help="run on a surface that already crosses itself, keeping (never adding) its crossings",
    )
    f.add_argument("-o", "--output", default="out/flow")
    f.add_argument("--threads", type=_thread_count)
    f.add_argument("--resume", action="store_true")
    f.add_argument("--force", action="store_true", help="with --resume: go on even though the scene changed")
    f.add_argument("-q", "--quiet", action="store_true")
    f.set_defaults(func=_cmd_flow)

    t = sub.add_parser("font", help="inflated 3D text: mesh a string, then inflate it by normal flow (paper §7.2)")
    t.add_argument("text", help='the text; "\\n" breaks lines')
    t.add_argument("--font", help="TrueType/OpenType file (default: DejaVu Sans)")
    t.add_argument("--height", type=float, default=0.3, help="cap height in scene units")
    t.add_argument("--edge-length", type=float, help="target edge length (default height/40)")
    t.add_argument("--beta", type=float, default=5e-3, help="push per step towards +z (< 0: towards -z)")
    t.add_argument("--smoothing", type=float, default=0.5, help="smoothing gamma >= 0 (the authors' smoothIntensity)")
    t.add_argument("--steps", type=int, default=10)
    t.add_argument("--dhat", type=float, default=1e-3, help="contact distance (absolute)")
    t.add_argument("-o", "--output", default="out/font")
    t.add_argument("--threads", type=_thread_count)
    t.add_argument("--resume", action="store_true")
    t.add_argument("--force", action="store_true", help="with --resume: go on even though the scene changed")
    t.add_argument("-q", "--quiet", action="store_true")
    t.set_defaults(func=_cmd_font)

    rp = sub.add_parser("repair", help="intersection-free clean-up of an animation sequence (paper §7.3)")
    rp.add_argument(
        "input", help="sequence: a folder or glob of OBJ frames, a .pvd VTU series, an .npz (vertices, faces) or USD"
    )
    rp.add_argument("-o", "--output", default="out/repair", help="output folder (the sequence, report, stats)")
    rp.add_argument("--dhat", type=float, default=1e-2, help="contact distance, absolute (the authors': 1e-2)")
    rp.add_argument(
        "--fixed",
        action="append",
        metavar="SELECTION",
        help="vertices that follow the input exactly: box:x0,y0,z0,x1,y1,z1 | relbox:... (0..1 of the first "
        "frame's bounding box) | indices:i,j,k|FILE (repeatable)",
    )
    rp.add_argument("--frames", metavar="A:B", help="repair frames A..B-1 (default all)")
    rp.add_argument(
        "--first-frame",
        choices=["error", "preserve"],
        default="error",
        help="a first frame that already crosses itself: stop with the pairs named, or keep its crossings",
    )
    rp.add_argument("--format", choices=["same", "obj", "pvd", "npz", "usd"], default="same", help="output form")
    rp.add_argument("--usd-prim", help="the mesh prim of a USD input (default: the first animated mesh)")
    rp.add_argument("--youngs-modulus", type=float, default=100.0)
    rp.add_argument("--thickness", type=float, default=0.01)
    rp.add_argument("--bending", type=float, default=1.0, help="bending multiplier (0: membrane only)")
    rp.add_argument("--newton-tol", type=float, help="RMS Newton step per vertex / dt to stop at (default 1e-3)")
    rp.add_argument(
        "--kappa-b",
        type=float,
        help="initial penalty pulling --fixed vertices onto the input when their move collides (default 1e4; "
        "1e8 when a fixed group passes through itself in the input, see docs/animation-repair.md)",
    )
    rp.add_argument(
        "--guard-fixed",
        action="store_true",
        help="keep pairs among --fixed vertices in contact too: the fixed parts never cross, but lag the input "
        "where it crosses itself (default: they follow the input exactly, as in the paper's code)",
    )
    rp.add_argument("--threads", type=_thread_count)
    rp.add_argument("--resume", action="store_true", help="continue an interrupted repair in the same folder")
    rp.add_argument("--force", action="store_true", help="with --resume: go on even though the scene changed")
    rp.add_argument("-q", "--quiet", action="store_true")
    rp.set_defaults(func=_cmd_repair)

    u = sub.add_parser("uv", help="cut the worst distortion of an OBJ's UV map, keeping it injective (paper §7.4)")
    u.add_argument("input", help="OBJ with texture coordinates (vt) on every face (or data:minmax/withUV/...)")
    u.add_argument("-o", "--output", required=True, help="OBJ to write: the input with only its vt lines changed")
    u.add_argument("--p", type=float, default=10.0, help="p of the p-norm symmetric Dirichlet energy (1: plain SD)")
    u.add_argument("--steps", type=int, default=200, help="step cap (it stops after a one-iteration step)")
    u.add_argument("--dhat", type=float, default=1e-3, help="contact distance in UV units")
    u.add_argument("--youngs-modulus", type=float, default=2e4)
    u.add_argument("--newton-tol", type=float, default=1e-3)
    u.add_argument("--preserve-overlaps", action="store_true", help="run on an overlapping layout, adding none")
    u.add_argument("--overwrite", action="store_true", help="allow OUTPUT to be the input file")
    u.add_argument("--report", help="folder for report, pictures and stats (default: OUTPUT's stem + _uv)")
    u.add_argument("--threads", type=_thread_count)
    u.add_argument("--resume", action="store_true")
    u.add_argument("--force", action="store_true", help="with --resume: go on even though the scene changed")
    u.add_argument("-q", "--quiet", action="store_true")
    u.set_defaults(func=_cmd_uv)

    c = sub.add_parser("check", help="report counts, closedness, inverted/degenerate elements, self-intersections")
    c.add_argument("meshes", nargs="+")
    c.set_defaults(func=_cmd_check)

    rr = sub.add_parser("render", help="draw a run's frames: chosen steps side by side, or one step from several views")
    rr.add_argument("run", help="a run's (or a stage's) output folder, holding vtu/frame_NNNNN.vtu")
    rr.add_argument("-o", "--output", help="the PNG to write (default: RUN/render.png)")
    rr.add_argument("--steps", type=int, nargs="+", help="steps to draw (default: the first and last frame written)")
    rr.add_argument(
        "--views", nargs="+", choices=["oblique", "side", "front", "above"], help="draw the last step from these views"
    )
    rr.add_argument("--hide-obstacles", action="store_true", help="leave the obstacles (tools, cages) out")
    rr.add_argument("--dim", type=int, choices=[2, 3], help="default: the run's scene.resolved.toml, else 3")
    rr.add_argument("--up", choices=["x", "y", "z"], help="the axis drawn upwards (default: the run's scene, else z)")
    rr.set_defaults(func=_cmd_render)

    d = sub.add_parser("demo", help="grow a generated blob inside a generated hourglass cage")
    d.add_argument("-o", "--output", default="out/demo")
    d.add_argument("--steps", type=int)
    d.add_argument("--threads", type=_thread_count)
    d.add_argument("-q", "--quiet", action="store_true")
    d.set_defaults(func=_cmd_demo)

    b = sub.add_parser("bench", help="run the paper's §6 benchmark suite")
    b.add_argument("--quick", action="store_true", help="the quick tier (under 15 minutes on 2 cores)")
    b.add_argument("--only", nargs="*", help="scene names to run")
    b.add_argument("-o", "--output", default="bench/results")
    b.add_argument("--threads", type=_thread_count)
    b.add_argument("--steps", type=int, help="override every scene's step count (for quick looks)")
    b.add_argument(
        "--solver",
        action="append",
        metavar="KEY=VALUE",
        help="set a [solver] key for every idp run (repeatable; e.g. contact_lookahead=3); recorded in the results",
    )
    b.add_argument(
        "--with-reference",
        action="store_true",
        help="run the authors' reference code (../shared/reference or $IDP_REFERENCE) in turn with idp on this "
        "machine and report same-run speed-ups",
    )
    b.add_argument("--runs", type=int, help="runs of each code per scene (default: 1 quick tier, 2 full tier)")
    b.add_argument("--reference-timeout", type=float, help="seconds after which a reference run is abandoned")
    b.add_argument(
        "--reference-blas",
        default="auto",
        metavar="auto|as-is|CORE",
        help="OpenBLAS kernels of the reference: 'auto' (default) sets OPENBLAS_CORETYPE when its OpenBLAS falls "
        "back to generic kernels on a CPU it does not know, 'as-is' never, or a core name (SkylakeX, Haswell, ...)",
    )
    b.set_defaults(func=_cmd_bench)

    bt = sub.add_parser(
        "batch",
        help="run many scenes or a parameter sweep as jobs on a Dask cluster (local by default); see docs/batch.md",
    )
    bt.add_argument("spec", help="batch spec file (TOML or JSON): a base scene with a grid or cases, and/or jobs")
    bt.add_argument("-o", "--output", help="output folder (default: out/<spec name>)")
    where = bt.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDR", help="a running dask.distributed scheduler (tcp://host:8786)")
    where.add_argument("--workers", type=_positive_int, help="workers of the local cluster (default: one per core)")
    where.add_argument("--serial", action="store_true", help="no Dask: the jobs one after another on this machine")
    bt.add_argument(
        "--threads-per-job", type=_positive_int, help="threads of each job (default: cores / workers, 1 on --scheduler)"
    )
    bt.add_argument("--retries", type=_non_negative_int, help="extra attempts of a failed job (default: the spec's)")
    bt.add_argument("--resume", action="store_true", help="skip finished jobs; continue the others from checkpoints")
    bt.add_argument("--dashboard", metavar="ADDR", help="serve the local cluster's Dask dashboard there (e.g. :8787)")
    bt.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    bt.set_defaults(func=_cmd_batch)
    return p


def main(argv: list[str] | None = None) -> int:
    if os.environ.get("IDP_BATCH_PARENT"):  # a job of `idp batch`: ends with the worker that started it
        from idp.applications.batch import watch_parent_from_env

        watch_parent_from_env()
    args = build_parser().parse_args(argv)
    if argv is None:  # the process's own command line: its shutdown need not walk the whole heap (idp._heap)
        from idp._heap import freeze_heap_at_exit

        freeze_heap_at_exit()
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="idp: %(levelname)s: %(message)s"
    )
    from idp.errors import CertificateError, IdpError, SolverError

    try:
        previous_handler = signal.signal(signal.SIGTERM, _on_sigterm)
        # Ctrl-C deferred the same way, unless SIGINT is ignored (a job of `idp batch`: the batch handles it)
        previous_sigint = (
            signal.signal(signal.SIGINT, _on_sigint) if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN else None
        )
    except ValueError:  # main() called from a thread other than the main one: the signals keep their handlers
        previous_handler = previous_sigint = None
    try:
        if args.func is _cmd_check:  # reads meshes only: no kernels, and no numba import for nothing
            return int(args.func(args) or 0)
        from idp.kernel_cache import announcing

        # a first run compiles the numba kernels (about a minute on 2 cores): said on stderr, not a silent wait
        with announcing(not getattr(args, "quiet", False)):
            return int(args.func(args) or 0)
    except CertificateError as exc:
        print(f"idp: certificate failure: {exc}", file=sys.stderr)
        return EXIT_CERTIFICATE
    except SolverError as exc:
        print(f"idp: solver error: {exc}", file=sys.stderr)
        return EXIT_SOLVER
    except IdpError as exc:
        print(f"idp: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt as exc:
        what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"idp: {what}; finished steps are on disk (resume with --resume)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError as exc:
        # the last resort: e.g. one vertex 10^11 away in a UV layout made Newton's steps so long that ipctk's CCD
        # asked for 13 GB (std::bad_alloc); a message and the solver's exit code rather than a traceback
        print(f"idp: solver error: out of memory ({exc or 'MemoryError'})", file=sys.stderr)
        return EXIT_SOLVER
    except BrokenPipeError:
        # stdout's reader went away ('idp check *.vtk | head'): no traceback, and none at exit either, when Python
        # flushes stdout again, so its descriptor is pointed at /dev/null
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return EXIT_BROKEN_PIPE
    finally:
        if previous_handler is not None:
            signal.signal(signal.SIGTERM, previous_handler)
        if previous_sigint is not None:
            signal.signal(signal.SIGINT, previous_sigint)


if __name__ == "__main__":
    sys.exit(main())
