"""Artificial time stepping (paper §4.1, §4.5): step loop, per-frame certificate, output, statistics.

Every finished step is on disk before the next one starts (frames, PVD index, stats.json and a
checkpoint), so an interrupted run loses nothing it had finished and can be resumed.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from idp import interrupts
from idp._blas_threads import quiet_blas
from idp._faults import kill_point
from idp.contact.certificate import Certifier
from idp.errors import CertificateError, SolverError
from idp.output.frames import FrameWriter
from idp.output.stats import StatsRecorder
from idp.solver.linear import LinearSolver
from idp.solver.newton import NewtonSettings, StepSolver

log = logging.getLogger("idp")


@dataclass
class RunSettings:
    steps: int = 60
    stop_when_stationary: bool = False
    stationary_tol: float = 1e-5
    stop_after_single_iteration: bool = False  # stop after the first step solved by one Newton iteration (§7.4)
    write_every: int = 1
    write_obj: bool = True
    write_vtu: bool = True
    write_png: bool = True
    on_nonconvergence: str = "warn"
    on_unmet_targets: str = "warn"  # a step ending with Dirichlet targets unmet: "warn" or "error" (stop)
    progress: bool = True
    resume: bool = False
    render_up: str = "z"  # the scene axis drawn upwards in frames.png (3D)


@dataclass
class RunResult:
    out_dir: Path
    steps_run: int
    x: np.ndarray
    summary: dict
    step_records: list = field(default_factory=list)
    parts: list = field(default_factory=list)


def _save_checkpoint(path: Path, x: np.ndarray, step: int, system, linear: LinearSolver | None = None) -> None:
    """Write the finished state atomically (temp file + rename): an interruption never leaves a torn file.

    Holds the positions, the step, the barrier stiffness, every per-step condition's own state (handle
    selections made during the run, rest frames changed by plasticity, ...), the Newton matrix's contact pattern
    and the linear solver's ordering state."""
    tmp = path.with_name(path.name + ".tmp.npz")
    extra = {}
    for i, cond in enumerate(system.conditions):
        if hasattr(cond, "state"):
            for k, v in cond.state().items():
                extra[f"cond{i}__{k}"] = v
    if getattr(system, "contact_pattern", None) is not None:
        for k, v in system.contact_pattern.state().items():
            extra[f"pattern__{k}"] = v
    for k, v in (linear.state() if linear is not None else {}).items():
        extra[f"linear__{k}"] = v
    np.savez(
        tmp,
        x=x,
        step=step,
        kappa=system.contact.kappa if system.contact else 0.0,
        kappa_max=system.contact.kappa_max if system.contact else 0.0,
        kappa_initialized=bool(system.contact.kappa_initialized) if system.contact else False,
        **extra,
    )
    kill_point("checkpoint")
    tmp.replace(path)


def _load_condition_states(ck: dict[str, np.ndarray], system, path: Path) -> None:
    """Restore the per-step conditions' state and the Newton matrix's contact pattern from a checkpoint."""
    for i, cond in enumerate(system.conditions):
        if hasattr(cond, "load_state"):
            pre = f"cond{i}__"
            try:
                cond.load_state({k[len(pre) :]: v for k, v in ck.items() if k.startswith(pre)})
            except ValueError as exc:
                raise SolverError(f"checkpoint {path}: {exc}; remove it to start the run over") from None
    if getattr(system, "contact_pattern", None) is not None:
        try:
            system.contact_pattern.load_state(
                {k.removeprefix("pattern__"): v for k, v in ck.items() if k.startswith("pattern__")}
            )
        except ValueError as exc:
            raise SolverError(f"checkpoint {path}: {exc}; remove it to start the run over") from None


def _read_checkpoint(path: Path) -> dict[str, np.ndarray]:
    """The arrays of an interrupted run's checkpoint; SolverError naming it when it is unreadable (truncated, not
    an npz, pickled data) or lacks the state every checkpoint holds."""
    try:  # the file is opened here: np.load leaves its own handle open when the data is not an npz
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            ck = {k: data[k] for k in data.files}
    except Exception as exc:  # zipfile, npy format and pickle refusals, EOF: numpy raises many types
        raise SolverError(
            f"checkpoint {path} is unreadable ({type(exc).__name__}: {exc}); remove it to start the run over"
        ) from None
    missing = [k for k in ("x", "step", "kappa", "kappa_max") if k not in ck or not isinstance(ck[k], np.ndarray)]
    if missing:
        raise SolverError(f"checkpoint {path} lacks {', '.join(missing)}; remove it to start the run over")
    real = [k for k in ("x", "kappa", "kappa_max") if ck[k].dtype.kind in "fiu" and np.isfinite(ck[k]).all()]
    bad = [k for k in ("x", "kappa", "kappa_max") if k not in real]
    bad += [k for k in ("step", "kappa", "kappa_max") if ck[k].shape != ()]
    if ck["step"].dtype.kind not in "iu" or ck["x"].ndim != 2:
        bad.append("step" if ck["x"].ndim == 2 else "x")
    done = ck.get("kappa_initialized")  # optional: absent in checkpoints written before it was kept
    if done is not None and (done.shape != () or done.dtype.kind not in "biu"):
        bad.append("kappa_initialized")
    if bad:
        raise SolverError(
            f"checkpoint {path}: {', '.join(sorted(set(bad)))} not as idp writes them; remove it to start the run over"
        )
    return ck


def _cell_data(system) -> dict | None:
    """VTU cell fields offered by the per-step conditions (e.g. accumulated plastic strain)."""
    out: dict = {}
    for cond in system.conditions:
        if hasattr(cond, "cell_data"):
            for name, per_part in cond.cell_data().items():
                out.setdefault(name, {}).update(per_part)
    return out or None


def _previous_stats(path: Path, last_step: int) -> tuple[list[dict], list[dict]]:
    """The records an interrupted run's stats.json holds for its start state and its steps up to ``last_step``
    (those after it are redone), and its list of earlier resumes; none if it is missing or unreadable."""
    from idp.output.stats import load_stats

    try:
        stats = load_stats(path)
        steps, resumes = list(stats["steps"]), list((stats.get("summary") or {}).get("resumes", []))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        log.warning("%s: the earlier steps' statistics could not be read; the resumed stats start here", path)
        return [], []
    kept = []
    for r in steps:
        step = int(r.get("step", 0))
        if (r.get("initial") and step == 0) or (not r.get("initial") and 1 <= step <= last_step):
            kept.append(r)
    return kept, [r for r in resumes if int(r.get("after_step", 0)) <= last_step]


def _fill_fraction(system, x) -> float | None:
    cage = system.meta.get("cage_volume")
    if not cage:
        return None
    return system.deformable_volume(x) / cage


def _condition_reports(system, x: np.ndarray) -> dict:
    """Per-step measures offered by the conditions (e.g. the normal flow's volume), by their ``report_key``."""
    out = {}
    for cond in system.conditions:
        key = getattr(cond, "report_key", None)
        if key is not None:
            out[key] = cond.report(system, x)
    return out


def nonconvergence_message(step: int, res, newton: NewtonSettings) -> str:
    """The warning (or error) for a step that ended without converging: the limit that stopped it and its last
    Newton decrement; a decrement already within tol says why it did not end the solve."""
    msg = f"step {step} did not converge ({_nonconvergence_reason(res, newton)}; decrement {res.decrement:.3e} "
    if res.decrement <= newton.tol and res.unconfirmed:
        return msg + f"<= tol {newton.tol:g}, but {res.unconfirmed})"
    return msg + f"> tol {newton.tol:g})"


def _nonconvergence_reason(res, newton: NewtonSettings) -> str:
    """Why a step stopped without converging, naming the limit that stopped it."""
    its = f"{res.iterations} Newton iteration{'s' if res.iterations != 1 else ''}"
    if res.hit_wall_limit:
        return f"hit the wall-clock limit solver.max_step_seconds = {newton.max_seconds:g} s after {its}"
    if res.hit_iteration_cap:
        return f"hit the iteration cap solver.max_newton_iterations = {newton.max_iterations}"
    return f"line search could not decrease the energy after {its}"


@quiet_blas()  # numpy's and scipy's BLAS run one thread while stepping (idp._blas_threads: spinning workers)
def run_simulation(
    system,
    newton: NewtonSettings,
    linear: LinearSolver,
    certifier: Certifier,
    out_dir: str | Path,
    settings: RunSettings,
    meta: dict | None = None,
    writer=None,
) -> RunResult:
    """Run ``settings.steps`` artificial time steps from ``system.x``; write everything to ``out_dir``.

    ``writer``: where frames go (``write(step, x, time=..., cell_data=...)``, ``close()``); default the OBJ/VTU/PVD
    :class:`~idp.output.frames.FrameWriter` under ``out_dir`` (animation repair writes the input's own form)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    if writer is None:
        writer = FrameWriter(
            out,
            system.parts,
            system.dim,
            write_obj=settings.write_obj,
            write_vtu=settings.write_vtu,
            fixed_mask=~system.free_mask.reshape(-1, system.dim).any(axis=1),
        )
    checkpoint = out / "checkpoint.npz"
    stats_path = out / "stats.json"
    solver = StepSolver(system, newton, linear, certifier=certifier)
    x_initial = system.x.copy()  # the start state (frame 0), also when resuming from a later checkpoint

    start_step = 0
    previous: list[dict] = []  # the interrupted run's records (start state, finished steps), kept as they were
    resumes: list[dict] = []  # where this run was resumed, with the certificate of the state it resumed from
    Path(str(checkpoint) + ".tmp.npz").unlink(missing_ok=True)  # a checkpoint write that was interrupted
    if settings.resume and checkpoint.exists():
        ck = _read_checkpoint(checkpoint)
        if ck["x"].shape != system.x.shape:
            raise SolverError(
                f"checkpoint {checkpoint} does not match this scene (shape {ck['x'].shape} vs {system.x.shape})"
            )
        system.x = ck["x"].copy()
        start_step = int(ck["step"])
        if system.contact is not None:
            system.contact.kappa, system.contact.kappa_max = float(ck["kappa"]), float(ck["kappa_max"])
            done = ck.get("kappa_initialized")  # absent in checkpoints written before it was kept
            system.contact.kappa_initialized = bool(done) if done is not None else system.contact.kappa > 0.0
        _load_condition_states(ck, system, checkpoint)
        linear.load_state({k.removeprefix("linear__"): v for k, v in ck.items() if k.startswith("linear__")})
        previous, resumes = _previous_stats(stats_path, start_step)
        log.info("resuming %s after step %d", out, start_step)
    if hasattr(writer, "resume") and start_step > 0:  # adopt the finished frames, drop any later or torn ones
        writer.resume(start_step, lambda frame: frame * math.sqrt(system.h))
    stats = StatsRecorder(stats_path, meta, steps=previous)  # the finished steps stay in the file throughout

    x0 = system.x.copy()
    cert0 = certifier.check(x0)
    if not cert0.ok:
        what = "start state" if start_step == 0 else f"checkpoint state (step {start_step})"
        raise CertificateError(f"the {what} fails the injectivity check: {cert0.describe()}")
    if start_step == 0:
        writer.write(0, x0, time=0.0)
    fill0 = _fill_fraction(system, x_initial)
    if start_step == 0 or not any(r.get("initial") for r in previous):
        rec0: dict[str, Any] = {"step": start_step, "certificate": cert0.to_dict()}
        rec0["fill_fraction"] = _fill_fraction(system, x0)
        rec0["initial"] = True
        rec0.update(_condition_reports(system, x0))
        stats.add_step(rec0)
    if start_step > 0:
        resumes.append({"after_step": start_step, "certificate": cert0.to_dict()})

    progress = None
    if settings.progress:
        from tqdm import tqdm

        progress = tqdm(total=settings.steps, initial=start_step, desc="idp", unit="step", dynamic_ncols=True)

    t_run = time.perf_counter()
    x = system.x
    total_its, uncertified, nonconverged, unmet_steps = 0, 0, 0, 0
    bc = system.step_constraint
    stopped_reason = "step count reached"
    step = start_step
    previous = [r for r in previous if not r.get("initial")]
    records: list[dict[str, Any]] = list(previous)
    total_its = sum(int(r.get("newton_iterations", 0)) for r in previous)
    nonconverged = sum(1 for r in previous if not r.get("converged", True))
    unmet_steps = sum(1 for r in previous if not r.get("dirichlet", {}).get("met", True))
    interrupt: KeyboardInterrupt | None = None
    # a signal during the steps waits for the next step or Newton iteration; one during the summary is dropped
    with interrupts.deferred():  # (the run is complete then) — see idp.interrupts
        try:
            for step in range(start_step + 1, settings.steps + 1):
                interrupts.checkpoint()
                t_step = time.perf_counter()
                system.set_rest_shape_for_step(step)
                for cond in system.conditions:
                    cond.before_step(system, step, x)
                if system.inertia_target is None:
                    x_new, res = solver.solve(x)
                else:
                    x_new, res = solver.solve(system.inertia_target, start=x, target_at_rest=system.target_at_rest)
                t_cert = time.perf_counter()
                cert = certifier.check(x_new)
                t_cert = time.perf_counter() - t_cert
                max_move = float(np.abs(x_new - x).max(initial=0.0))
                x = x_new
                system.x = x
                total_its += res.iterations
                step_time = time.perf_counter() - t_step
                fill = _fill_fraction(system, x)
                timings = dict(res.timings)
                timings["certificate"] = t_cert
                timings["other"] = max(step_time - sum(timings.values()), 0.0)
                rec: dict[str, Any] = {
                    "step": step,
                    "wall_time": step_time,
                    "newton_iterations": res.iterations,
                    "converged": res.converged,
                    "exact_minimiser": res.exact,
                    "hit_iteration_cap": res.hit_iteration_cap,
                    "hit_wall_limit": res.hit_wall_limit,
                    "line_search_failed": res.line_search_failed,
                    "newton_decrement": res.decrement,
                    "decrement_unconfirmed": res.unconfirmed,
                    "alphas": res.alphas,
                    "ccd_alphas": res.ccd_alphas,
                    "inversion_alphas": res.inversion_alphas,
                    "decrements": res.decrements,
                    "gradient_descent_fallbacks": res.gradient_descent_fallbacks,
                    "pcg_iterations": res.pcg_iterations,
                    "exact_refactorizations": res.exact_refactorizations,
                    "distorted_folds": res.distorted_folds,
                    "lookahead_iterations": res.lookahead_iterations,
                    "island_iterations": res.island_iterations,
                    "max_islands": res.max_islands,
                    "contacts": res.num_contacts,
                    "kappa": res.kappa,
                    "energy": res.energy,
                    "elastic_energy": res.elastic_energy,
                    "barrier_energy": res.barrier_energy,
                    "min_distance": res.min_distance,
                    "max_displacement": max_move,
                    "fill_fraction": fill,
                    "certificate": cert.to_dict(),
                    "timings": timings,
                }
                bc_report = bc.report(x, system.meta.get("dhat")) if bc is not None and bc.active else None
                if bc_report is not None:
                    rec["dirichlet"] = bc_report
                    if not bc_report["met"]:
                        unmet_steps += 1
                rec.update(_condition_reports(system, x))
                records.append(rec)
                stats.add_step(rec)
                for cond in system.conditions:
                    if hasattr(cond, "after_step"):
                        cond.after_step(system, step, x)
                if not cert.ok:
                    uncertified += 1
                    raise CertificateError(f"step {step} failed the injectivity certificate: {cert.describe()}")
                if not res.converged:
                    nonconverged += 1
                    msg = nonconvergence_message(step, res, newton)
                    if settings.on_nonconvergence == "error":  # the certified state is kept, as for unmet targets
                        writer.write(step, x, time=step * math.sqrt(system.h), cell_data=_cell_data(system))
                        _save_checkpoint(checkpoint, x, step, system, linear)
                        raise SolverError(msg)
                    log.warning(msg)
                if bc_report is not None and not bc_report["met"]:
                    msg = (
                        f"step {step} ended with Dirichlet targets unmet: max distance {bc_report['residual_max']:.3e} "
                        f"(rms {bc_report['residual_rms']:.3e}), kappa_B {bc_report['kappa_B']:.3g}"
                    )
                    if settings.on_unmet_targets == "error":
                        writer.write(step, x, time=step * math.sqrt(system.h), cell_data=_cell_data(system))
                        _save_checkpoint(checkpoint, x, step, system, linear)
                        raise SolverError(msg)
                    log.warning(msg)
                last = step == settings.steps
                stationary = settings.stop_when_stationary and max_move < settings.stationary_tol
                single = settings.stop_after_single_iteration and res.converged and res.iterations <= 1
                if last or stationary or single or step % settings.write_every == 0:
                    writer.write(step, x, time=step * math.sqrt(system.h), cell_data=_cell_data(system))
                _save_checkpoint(checkpoint, x, step, system, linear)
                if progress is not None:
                    post: dict[str, Any] = {"its": res.iterations, "contacts": res.num_contacts}
                    if bc_report is not None:
                        post["BC"] = "met" if bc_report["met"] else f"UNMET {bc_report['residual_max']:.1e}"
                    if fill is not None:
                        post["fill"] = f"{100 * fill:.2f}%"
                    elif rec.get("flow", {}).get("volume_ratio") is not None:
                        post["volume"] = f"x{rec['flow']['volume_ratio']:.3f}"
                    else:
                        post["E"] = f"{res.energy:.3e}"
                    progress.set_postfix(post)
                    progress.update(1)
                if stationary:
                    if step % settings.write_every != 0:
                        writer.write(step, x, time=step * math.sqrt(system.h), cell_data=_cell_data(system))
                    stopped_reason = f"stationary (max |dx| {max_move:.2e} < {settings.stationary_tol:g})"
                    break
                if single:
                    stopped_reason = f"step {step} converged in {res.iterations} Newton iteration(s)"
                    break
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM turned into one by the CLI: re-raised once on disk
            interrupt = exc
            stopped_reason = f"interrupted during step {step}"
            log.warning("interrupted: everything up to step %d is on disk", step - 1)
            step -= 1
        finally:
            if progress is not None:
                progress.close()
            writer.close()

        wall = time.perf_counter() - t_run + sum(float(r.get("wall_time", 0.0)) for r in previous)
        steps_done = len(records)  # the whole run's, also when it was resumed
        summary = {
            "steps_run": steps_done,
            "last_step": records[-1]["step"] if records else start_step,
            "stopped": stopped_reason,
            "wall_time": wall,
            "newton_iterations": total_its,
            "nonconverged_steps": nonconverged,
            "steps_with_unmet_targets": unmet_steps,
            "uncertified_frames": uncertified,
            "all_certified": uncertified == 0,
            "fill_fraction": _fill_fraction(system, x),
            **_condition_reports(system, x),
            "dhat": system.meta.get("dhat"),
            "initial_fill_fraction": fill0,
            "min_distance": min((r["certificate"]["min_distance"] for r in records), default=math.inf),
            "timings": {
                k: float(sum(r["timings"].get(k, 0.0) for r in records))
                for k in (records[0]["timings"] if records else {})
            },
            "linear_solver": getattr(linear, "stats", {}),
        }
        if resumes:
            summary["resumes"] = resumes
        guard = getattr(linear, "memory_guard", None)
        if guard is not None and guard.peak is not None:  # the largest step-memory estimate of this process
            summary["memory_estimate"] = guard.peak.to_dict()
        stats.set_summary(summary)
        if settings.write_png and records:
            try:
                from idp.output.render import render_frames_png

                render_frames_png(
                    out / "frames.png",
                    system.parts,
                    [("step 0", x_initial), (f"step {summary['last_step']}", x)],
                    dim=system.dim,
                    up=settings.render_up,
                )
            except Exception as exc:  # a picture must never lose a finished run
                log.warning("could not render frames.png: %s", exc)
    if interrupt is not None:
        raise interrupt
    return RunResult(out, steps_done, x, summary, records, system.parts)
