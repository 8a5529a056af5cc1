"""Batches of runs (``idp batch SPEC.toml``): many scenes, a parameter sweep, many repairs, each job its own process,
on a Dask cluster — a local one by default, or an existing ``dask.distributed`` scheduler given by address.

Each job (:mod:`idp.scene.batch_schema`) has a folder ``OUT/jobs/<name>/``::

    scene.toml      the resolved scene it runs (overrides applied, every path absolute, every default filled in)
    run/            the run's output (frames, stats.json, checkpoint.npz; report.json for a repair)
    logs/           attempt-N.out / attempt-N.err: what each attempt printed
    attempts.json   one record per attempt (worker, process ids, start, end, exit code, error)
    job.json        written last and atomically when an attempt ends: status, exit code, summary, error

A job is ``python -m idp run scene.toml -o run --resume -q --threads N`` started as a subprocess from a Dask task:
a crash, segfault or out-of-memory kill of one job cannot take a worker down, and a job whose worker died is run
again elsewhere, resuming from its checkpoint. The subprocess exits with its worker (the worker's death is
its parent's: ``PR_SET_PDEATHSIG`` on Linux, and a watch on the parent process everywhere), so a re-run never
shares its folder with an orphan. A nonzero exit raises in the task, so Dask retries it (``retries``); after
the last retry the job is reported failed with its error while the other jobs go on.

The results table (``results.csv``, ``results.parquet`` when pyarrow is installed, ``results.md``) has a row per
job, and ``batch.json`` the spec, the cluster and every job's status. With ``resume`` a job whose ``job.json``
says it finished with the same scene is skipped; the others continue from their checkpoints.

Dask is imported only here, and only when a batch runs on it (``serial=True`` needs no Dask).
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import hashlib
import io
import json
import logging
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from idp import interrupts
from idp.errors import IdpError, MissingDependencyError, SceneError
from idp.fs import check_output_dir, make_output_dir

log = logging.getLogger("idp")

__all__ = ["COLUMNS", "BatchResult", "JobFailed", "run_batch", "run_job"]

#: the results table's columns (then one column per overridden key path)
COLUMNS = [
    "job",
    "overrides",
    "status",
    "attempts",
    "wall_time",
    "steps",
    "newton_iterations",
    "all_certified",
    "fill_fraction",
    "min_distance",
    "deviation",
    "error",
    "exit_code",
    "job_time",
]
#: exit codes of ``idp run`` (idp.cli) a job reports in words
_EXIT_WORDS = {2: "input error", 3: "certificate failure", 4: "solver error", 130: "interrupted"}
_THREAD_VARS = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_PARENT_VAR = "IDP_BATCH_PARENT"  # set in a job's environment: the job exits when this process (its worker) does
_ERROR_LINES = 20  # lines of a failed attempt's stderr kept in job.json


class JobFailed(Exception):
    """A job's process ended with a nonzero exit (raised in its task, so that Dask retries it)."""


class JobCancelled(Exception):
    """The batch was stopped while the job ran (its process was terminated)."""


@dataclass
class BatchResult:
    """What a batch did: one row per job (the results table), where the tables are, and the counts."""

    out: Path
    rows: list[dict[str, Any]]
    wall_time: float
    cluster: str
    skipped: list[str] = field(default_factory=list)  # finished by an earlier run (resume)
    tables: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "ok"]

    @property
    def ok(self) -> bool:
        return not self.failed


# ---------------------------------------------------------------------------------------------
# Small file helpers (every file a reader may look at mid-batch is replaced atomically)


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _write_json(path: Path, data: Any) -> None:
    from idp.output.stats import to_jsonable

    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    tmp.write_text(json.dumps(to_jsonable(data), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


# ---------------------------------------------------------------------------------------------
# The job's own process: exit with the worker that started it


def watch_parent_from_env() -> None:
    """In a job's process (``IDP_BATCH_PARENT`` set by :func:`run_job`): exit as soon as the worker that started
    it is gone, so a killed worker leaves no orphan writing into a folder its job's re-run uses."""
    text = os.environ.get(_PARENT_VAR)
    if not text:
        return
    try:
        parent = int(text)
    except ValueError:
        return
    if sys.platform.startswith("linux"):
        try:  # the kernel kills this process when its parent dies (immediate)
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the line above
        os._exit(EXIT_ORPHANED)

    def watch() -> None:  # everywhere: poll the parent process (reparented once it has died)
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(EXIT_ORPHANED)

    threading.Thread(target=watch, name="idp-batch-parent-watch", daemon=True).start()


EXIT_ORPHANED = 137  # as if killed (128 + SIGKILL) with the worker


# ---------------------------------------------------------------------------------------------
# One job (runs inside a Dask task, or in this process with serial=True)


def _job_summary(run_dir: Path) -> dict[str, Any]:
    """The numbers of a job's run folder: a staged run's stages.json, else stats.json's summary, with the
    sequence's largest deviation from report.json for a repair."""
    from idp.output.stats import load_stats

    s: dict[str, Any] = {}
    stages = _read_json(run_dir / "stages.json")
    if isinstance(stages, dict):
        s = stages
    elif (run_dir / "stats.json").is_file():
        try:
            s = load_stats(run_dir / "stats.json").get("summary") or {}
        except (OSError, ValueError):
            s = {}
    out = {
        "wall_time": s.get("wall_time"),
        "steps": s.get("last_step", s.get("steps_run")),
        "newton_iterations": s.get("newton_iterations"),
        "all_certified": s.get("all_certified"),
        "fill_fraction": s.get("fill_fraction"),
        "min_distance": s.get("min_distance"),
        "deviation": None,
        "stopped": s.get("stopped"),
    }
    report = _read_json(run_dir / "report.json")
    if isinstance(report, dict) and isinstance(report.get("sequence"), dict):
        out["deviation"] = report["sequence"].get("max_deviation")
    return out


def _error_text(rc: int, err_file: Path) -> tuple[str, list[str]]:
    """One line for the table (the job's own ``idp: ...`` message where it printed one) and the stderr tail."""
    try:
        lines = [ln.rstrip() for ln in err_file.read_text(encoding="utf-8", errors="replace").splitlines()]
    except OSError:
        lines = []
    lines = [ln for ln in lines if ln.strip()]
    tail = lines[-_ERROR_LINES:]
    if rc < 0:
        try:
            what = f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            what = f"killed by signal {-rc}"
    else:
        what = f"exit code {rc}" + (f" ({_EXIT_WORDS[rc]})" if rc in _EXIT_WORDS else "")
    own = [ln for ln in lines if ln.startswith("idp: ")]
    last = own[-1] if own else (lines[-1] if lines else "")
    return (f"{what}: {last}" if last else what), tail


def _job_env(threads: int) -> dict[str, str]:
    env = dict(os.environ)
    for var in _THREAD_VARS:
        env[var] = str(threads)
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 for its workers (distributed.nanny.pre-spawn-environ), so
    # that they hand freed memory back: inherited by a job, glibc's malloc trims after every large free, which
    # made the bunny sweep's jobs a third slower (docs/batch.md). A job allocates like `idp run` does alone.
    env.pop("MALLOC_TRIM_THRESHOLD_", None)
    root = Path(__file__).resolve().parents[2]
    if root.name not in ("site-packages", "dist-packages"):  # a source checkout: the job runs this worker's idp
        env["PYTHONPATH"] = os.pathsep.join([str(root), *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    env[_PARENT_VAR] = str(os.getpid())
    return env


def _worker_address() -> str | None:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return None


def _announce(topic: str | None, job: str) -> None:
    """Tell the batch's progress that the job started (a Dask worker event; nothing outside a worker)."""
    if not topic:
        return
    try:
        from distributed import get_worker

        get_worker().log_event(topic, {"job": job, "event": "start"})
    except (ImportError, ValueError):
        pass


def run_job(
    job_dir: str,
    *,
    job: str,
    threads: int = 1,
    stop_file: str | None = None,
    topic: str | None = None,
    poll: float = 0.25,
) -> dict[str, Any]:
    """Run one attempt of a job: ``python -m idp run JOB/scene.toml -o JOB/run --resume -q --threads N`` in its own
    process, with its thread counts set; record the attempt, write ``job.json`` last. Returns the job's record;
    raises :class:`JobFailed` (nonzero exit: Dask retries) or :class:`JobCancelled` (``stop_file`` appeared)."""
    d = Path(job_dir)
    threads = max(1, min(int(threads), os.cpu_count() or 1))
    attempts_file = d / "attempts.json"
    history = _read_json(attempts_file) or []
    for a in history:  # a worker that died mid-attempt never closed its record
        if a.get("ended") is None and "lost" not in a:
            a["lost"] = True
            a["error"] = "its worker went away (killed or lost) before it finished; run again"
    n = len(history) + 1
    me: dict[str, Any] = {
        "attempt": n,
        "host": socket.gethostname(),
        "worker": _worker_address(),
        "worker_pid": os.getpid(),
        "started": _now(),
        "ended": None,
    }
    history.append(me)
    _write_json(attempts_file, history)
    _announce(topic, job)

    logs = d / "logs"
    logs.mkdir(exist_ok=True)
    out_file, err_file = logs / f"attempt-{n}.out", logs / f"attempt-{n}.err"
    command = [sys.executable, "-m", "idp", "run", "scene.toml", "-o", "run", "--resume", "-q"]
    command += ["--threads", str(threads)]
    t0 = time.perf_counter()
    cancelled = False
    with open(out_file, "wb") as fo, open(err_file, "wb") as fe:
        proc = subprocess.Popen(
            command, cwd=d, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL, env=_job_env(threads),
            start_new_session=True,  # a Ctrl-C in the terminal is the batch's to handle, not each job's
        )  # fmt: skip
        me["pid"] = proc.pid
        _write_json(attempts_file, history)
        try:
            while True:
                try:
                    rc = proc.wait(timeout=poll)
                    break
                except subprocess.TimeoutExpired:
                    if stop_file and os.path.exists(stop_file):
                        cancelled = True
                        rc = _stop(proc)
                        break
        except BaseException:  # interrupted here (serial batch): the job must not outlive it
            _stop(proc)
            me.update(ended=_now(), exit_code=None, error="interrupted")
            _write_json(attempts_file, history)
            raise
    job_time = time.perf_counter() - t0
    summary = _job_summary(d / "run")
    error, tail = (None, []) if rc == 0 else _error_text(rc, err_file)
    if cancelled:
        error = "the batch was stopped while it ran"
    me.update(ended=_now(), exit_code=rc, job_time=job_time, error=error)
    _write_json(attempts_file, history)
    record = {
        "job": job,
        "status": "ok" if rc == 0 and not cancelled else ("cancelled" if cancelled else "failed"),
        "exit_code": rc,
        "attempts": n,
        "error": error,
        "error_tail": tail,
        "job_time": job_time,
        "summary": summary,
        "command": command,
        "threads": threads,
        "host": me["host"],
        "worker": me["worker"],
        "scene_sha256": _sha((d / "scene.toml").read_text(encoding="utf-8")),
        "finished": _now(),
    }
    if cancelled:
        raise JobCancelled(f"job {job}: {error}")
    _write_json(d / "job.json", record)  # last: the job's done marker (a failed one is run again on resume)
    if rc != 0:
        raise JobFailed(f"job {job}: {error}")
    return record


def _stop(proc: subprocess.Popen) -> int:
    """End a job's process: SIGTERM, then SIGKILL after 10 s; its exit code."""
    proc.terminate()
    try:
        return proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


# ---------------------------------------------------------------------------------------------
# The batch


@dataclass
class _Plan:
    name: str
    dir: Path
    overrides: dict[str, Any]
    origin: str
    scene_sha: str
    done: dict[str, Any] | None = None  # job.json of a finished job (skipped)


def run_batch(
    spec: str | Path,
    out: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    threads_per_job: int | None = None,
    retries: int | None = None,
    resume: bool = False,
    serial: bool = False,
    progress: bool = True,
    dashboard: str | None = None,
    on_start: Callable[[Any], None] | None = None,
) -> BatchResult:
    """Run every job of the batch spec file ``spec`` into ``out/jobs/<name>/`` and write the results table.

    ``scheduler``: the address of a running ``dask.distributed`` scheduler (``tcp://host:8786``; ``out`` and
    the scenes' files must then be on a file system every worker sees at the same paths); by default a local
    cluster of ``workers`` processes (default: one per core), one thread each. ``serial``: no Dask, the jobs one
    after another in this process's children. ``threads_per_job``: numba/BLAS/TBB threads of each job (default:
    the spec's, else cores / workers locally, 1 on a scheduler, all cores in serial). ``retries``: extra attempts
    after a failure (default: the spec's). ``resume``: skip the jobs that finished (with the same scene) and
    continue the others from their checkpoints; without it every job starts afresh. ``dashboard``: address of
    the local cluster's Dask dashboard (``:8787``; default none). ``on_start(client)`` is
    called once the Dask client is connected (tests use it to reach the cluster).

    Bad specs raise :class:`~idp.errors.SceneError` before anything runs; a failed job does not raise (its row
    says why): check ``result.ok``. KeyboardInterrupt stops the running jobs and leaves the batch resumable.
    """
    from idp.scene.batch_schema import load_batch

    if scheduler is not None and workers is not None:
        raise SceneError(
            "a batch on a running scheduler uses the workers that joined it: give --workers or --scheduler"
        )
    if serial and scheduler is not None:
        raise SceneError("--serial runs the jobs here, one after another: it takes no --scheduler")
    if not serial:
        _require_dask()
    spec_path = Path(spec)
    batch, jobs = load_batch(spec_path)
    cores = os.cpu_count() or 1
    n_workers = workers if workers is not None else cores
    if n_workers < 1:
        raise SceneError(f"workers: must be >= 1 (got {n_workers})")
    n_retries = retries if retries is not None else batch.retries
    if n_retries < 0:
        raise SceneError(f"retries: must be >= 0 (got {n_retries})")
    out = make_output_dir(check_output_dir(out))
    threads = threads_per_job or batch.threads_per_job
    if threads is None:
        threads = cores if serial else (1 if scheduler else max(1, cores // n_workers))
    if serial:
        cluster_text = f"serial (one job at a time, {threads} thread(s) each)"
    elif scheduler:
        cluster_text = f"scheduler {scheduler}, {threads} thread(s) per job"
    else:
        cluster_text = f"local cluster of {n_workers} worker(s) x 1 job, {threads} thread(s) per job"

    plans = _prepare(jobs, out, resume)
    run_id = uuid.uuid4().hex[:12]
    stop_file = out / f".stop-{run_id}"
    info: dict[str, Any] = {
        "name": batch.name,
        "spec_file": str(spec_path.absolute()),
        "spec": batch.model_dump(mode="json"),
        "out": str(out.absolute()),
        "cluster": cluster_text,
        "threads_per_job": threads,
        "retries": n_retries,
        "resume": resume,
        "started": _now(),
        "status": "running",
        "jobs": [{"job": p.name, "origin": p.origin, "overrides": p.overrides, "status": "pending"} for p in plans],
    }
    _write_json(out / "batch.json", info)
    records: dict[str, dict[str, Any]] = {p.name: p.done for p in plans if p.done is not None}
    skipped = [p.name for p in plans if p.done is not None]
    todo = [p for p in plans if p.done is None]
    _compile_kernels([j.scene for j, p in zip(jobs, plans, strict=True) if p.done is None], progress)
    bar = _Progress(len(plans), len(skipped), progress)
    t0 = time.perf_counter()
    interrupted = False
    try:
        with interrupts.immediate():  # a SIGTERM to `idp batch` raises here: the jobs are stopped below
            if serial:
                _run_serial(todo, threads, n_retries, stop_file, records, bar)
            else:
                _run_dask(
                    todo, threads, n_retries, stop_file, records, bar, scheduler, n_workers, run_id, on_start, dashboard
                )
    except KeyboardInterrupt:
        interrupted = True
    except BaseException as exc:  # e.g. the scheduler cannot be reached: said in batch.json too
        info.update(status="error", error=f"{type(exc).__name__}: {exc}", finished=_now())
        _write_json(out / "batch.json", info)
        raise
    finally:
        bar.close()
        if not (interrupted and scheduler):  # a remote worker's job may not have seen it yet: left in place
            try:
                stop_file.unlink()
            except OSError:
                pass
    wall = time.perf_counter() - t0
    rows = [_row(p, records.get(p.name)) for p in plans]
    tables = _write_tables(out, batch.name, rows, wall, cluster_text, skipped)
    info.update(
        status="interrupted" if interrupted else "done",
        finished=_now(),
        wall_time=wall,
        counts={s: sum(r["status"] == s for r in rows) for s in ("ok", "failed", "not run")},
        skipped=skipped,
        jobs=[
            {**j, "status": r["status"], "attempts": r["attempts"], "error": r["error"]}
            for j, r in zip(info["jobs"], rows, strict=True)
        ],
    )
    _write_json(out / "batch.json", info)
    if interrupted:
        raise KeyboardInterrupt
    return BatchResult(out, rows, wall, cluster_text, skipped, tables)


def _compile_kernels(scenes: list[Any], progress: bool) -> None:
    """The numba kernels the jobs need, compiled here once (both cores, with a progress bar) rather than by every
    worker at the same time on a cold cache; a warm cache costs one index read per kernel."""
    from idp.kernel_cache import announcing, prepare, scene_kernels

    kernels = list(dict.fromkeys(k for scene in scenes for k in scene_kernels(scene)))
    with announcing(progress):
        prepare(kernels)


def _require_dask() -> None:
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise MissingDependencyError(
            "idp batch runs its jobs on Dask, which is not installed: pip install 'idp[batch]' "
            "(or run the jobs one after another here with --serial)"
        ) from None


def _prepare(jobs: list[Any], out: Path, resume: bool) -> list[_Plan]:
    """Job folders with their scene files; on resume, which jobs finished (same scene) and which folders hold a
    run of another scene (an error: resuming it would continue the wrong run)."""
    plans, stale = [], []
    for job in jobs:
        d = out / "jobs" / job.name
        sha = _sha(job.scene_toml)
        scene_file = d / "scene.toml"
        done = None
        if resume and scene_file.is_file():
            if _sha(scene_file.read_text(encoding="utf-8")) != sha:
                stale.append(str(d))
                continue
            rec = _read_json(d / "job.json")
            if isinstance(rec, dict) and rec.get("status") == "ok" and rec.get("scene_sha256") == sha:
                done = {**rec, "skipped": True}
        elif not resume and d.exists():
            shutil.rmtree(d)
        plans.append(_Plan(job.name, d, job.overrides, job.origin, sha, done))
    if stale:
        raise SceneError(
            "cannot resume: these job folders hold runs of a different scene (the spec or a scene it names changed "
            "since): " + ", ".join(stale) + "; remove them, or run the batch without --resume to start every job afresh"
        )
    for p, job in zip(plans, jobs, strict=True):
        if p.done is None:
            p.dir.mkdir(parents=True, exist_ok=True)
            if not (p.dir / "scene.toml").is_file():
                _write_text(p.dir / "scene.toml", job.scene_toml)
    return plans


class _Progress:
    """A tqdm bar over the jobs with done/running/failed counts (nothing when ``enabled`` is False)."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.done, self.failed, self.running = done, 0, 0
        self.lock = threading.Lock()
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, desc="idp batch", unit="job", dynamic_ncols=True)
            self._post()

    def _post(self) -> None:
        if self.bar is not None:
            self.bar.set_postfix(done=self.done, running=self.running, failed=self.failed, refresh=True)

    def set_running(self, n: int) -> None:
        with self.lock:
            if n != self.running:
                self.running = n
                self._post()

    def finished(self, ok: bool) -> None:
        with self.lock:
            if ok:
                self.done += 1
            else:
                self.failed += 1
            if self.bar is not None:
                self.bar.update(1)
            self._post()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _failure_record(p: _Plan, error: str) -> dict[str, Any]:
    """job.json of a job that failed outside its own process (its worker died too often, the task was lost)."""
    rec = _read_json(p.dir / "job.json")
    attempts = len(_read_json(p.dir / "attempts.json") or [])
    if not isinstance(rec, dict) or rec.get("status") == "ok" or rec.get("attempts") != attempts:
        rec = {
            "job": p.name,
            "status": "failed",
            "exit_code": None,
            "attempts": attempts,
            "error": error,
            "error_tail": [],
            "summary": _job_summary(p.dir / "run"),
            "scene_sha256": p.scene_sha,
            "finished": _now(),
        }
        _write_json(p.dir / "job.json", rec)
    return rec


def _run_serial(todo: list[_Plan], threads: int, retries: int, stop_file: Path, records: dict, bar: _Progress) -> None:
    for p in todo:
        bar.set_running(1)
        for attempt in range(retries + 1):
            try:
                records[p.name] = run_job(str(p.dir), job=p.name, threads=threads, stop_file=str(stop_file))
                break
            except JobFailed:
                if attempt == retries:
                    records[p.name] = _read_json(p.dir / "job.json")
        bar.set_running(0)
        bar.finished(records[p.name].get("status") == "ok")


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored meanwhile (in the main thread; elsewhere nothing changes): processes started here keep
    ignoring it, so a terminal's Ctrl-C reaches the batch alone, not every worker with a traceback of its own."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _run_dask(
    todo: list[_Plan],
    threads: int,
    retries: int,
    stop_file: Path,
    records: dict,
    bar: _Progress,
    scheduler: str | None,
    n_workers: int,
    run_id: str,
    on_start: Callable[[Any], None] | None,
    dashboard: str | None,
) -> None:
    from distributed import Client, LocalCluster

    cluster = None
    client = None
    # Dask's own logs (workers starting, a task's exception, a worker restarted) only with -v: a job's failure is
    # reported in its row, a lost worker by its job's attempts
    quiet = not log.isEnabledFor(logging.INFO)
    dask_log = logging.getLogger("distributed")
    level = dask_log.level
    if quiet:
        dask_log.setLevel(logging.CRITICAL)
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="10s")
            except OSError as exc:
                raise IdpError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        else:
            with _sigint_ignored():  # inherited by the workers: a Ctrl-C is the batch's to handle (it closes them)
                cluster = LocalCluster(
                    n_workers=n_workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=dashboard,
                    silence_logs=logging.CRITICAL if quiet else logging.INFO,
                )
            client = Client(cluster)
        if on_start is not None:
            on_start(client)
        topic = f"idp-batch-{run_id}"
        started: set[str] = set()
        lock = threading.Lock()

        def on_event(event: Any) -> None:
            _, msg = event
            if isinstance(msg, dict) and msg.get("event") == "start":
                with lock:
                    started.add(str(msg.get("job")))

        try:
            client.subscribe_topic(topic, on_event)
        except Exception:  # progress only: a scheduler without events still runs the batch
            topic = ""
        futures = {
            client.submit(
                run_job,
                str(p.dir.absolute()),
                job=p.name,
                threads=threads,
                stop_file=str(stop_file.absolute()),
                topic=topic or None,
                key=f"idp-batch-{run_id}-{p.name}",
                retries=retries,
                pure=False,
            ): p
            for p in todo
        }
        remaining = dict(futures)
        try:
            while remaining:
                for fut in [f for f in remaining if f.done()]:
                    p = remaining.pop(fut)
                    if fut.status == "finished":
                        records[p.name] = fut.result()
                    else:
                        why: Any
                        try:
                            why = fut.exception()
                        except BaseException as e:  # cancelled
                            why = e
                        records[p.name] = _failure_record(p, f"{type(why).__name__}: {why}")
                    with lock:
                        started.discard(p.name)
                    bar.finished(records[p.name].get("status") == "ok")
                with lock:
                    bar.set_running(sum(1 for p in remaining.values() if p.name in started))
                time.sleep(0.2)
        except BaseException:
            stop_file.touch()  # every running job ends its process (a remote worker's too)
            client.cancel(list(remaining))
            raise
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        dask_log.setLevel(level)


# ---------------------------------------------------------------------------------------------
# Results


def _num(v: Any) -> Any:
    return v if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _row(p: _Plan, rec: dict[str, Any] | None) -> dict[str, Any]:
    overrides = "; ".join(f"{k}={json.dumps(v) if isinstance(v, str) else v}" for k, v in p.overrides.items())
    if rec is None:
        attempts = len(_read_json(p.dir / "attempts.json") or [])
        row = {"job": p.name, "overrides": overrides, "status": "not run", "attempts": attempts}
        row.update({k: None for k in COLUMNS if k not in row})
        row["error"] = "the batch was stopped before the job finished"
    else:
        s = rec.get("summary") or {}
        row = {
            "job": p.name,
            "overrides": overrides,
            "status": rec.get("status", "failed"),
            "attempts": rec.get("attempts"),
            "wall_time": _num(s.get("wall_time")),
            "steps": _num(s.get("steps")),
            "newton_iterations": _num(s.get("newton_iterations")),
            "all_certified": s.get("all_certified") if isinstance(s.get("all_certified"), bool) else None,
            "fill_fraction": _num(s.get("fill_fraction")),
            "min_distance": _num(s.get("min_distance")),
            "deviation": _num(s.get("deviation")),
            "error": rec.get("error"),
            "exit_code": rec.get("exit_code"),
            "job_time": _num(rec.get("job_time")),
        }
    row["_keys"] = dict(p.overrides)
    return row


def _key_columns(rows: list[dict[str, Any]]) -> list[str]:
    keys: dict[str, None] = {}
    for r in rows:
        keys.update(dict.fromkeys(r["_keys"]))
    return [k for k in keys if k not in COLUMNS]


def _cell(v: Any) -> Any:
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return json.dumps(v, separators=(",", ":"), default=str)


def _table(rows: list[dict[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    keys = _key_columns(rows)
    flat = []
    for r in rows:
        d = {k: r[k] for k in COLUMNS}
        d.update({k: _cell(r["_keys"].get(k)) for k in keys})
        flat.append(d)
    return COLUMNS + keys, flat


def _csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf" if v < 0 else "nan")
    return str(v)


def _parquet(path: Path, columns: list[str], flat: list[dict[str, Any]]) -> bool:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    arrays = {}
    for c in columns:
        vals = [r[c] for r in flat]
        present = [v for v in vals if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            typ = pa.bool_()
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            typ = pa.int64()
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            typ = pa.float64()
            vals = [float(v) if v is not None else None for v in vals]
        else:
            typ = pa.string()
            vals = [_csv_value(v) if v is not None else None for v in vals]
        arrays[c] = pa.array(vals, type=typ)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(pa.table(arrays), tmp)
    os.replace(tmp, path)
    return True


def _md_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "**no**"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    text = str(v).replace("|", "\\|").replace("\n", " ")
    return text if len(text) <= 90 else text[:87] + "..."


def _write_tables(
    out: Path, name: str, rows: list[dict[str, Any]], wall: float, cluster: str, skipped: list[str]
) -> list[Path]:
    columns, flat = _table(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in flat:
        w.writerow([_csv_value(r[c]) for c in columns])
    _write_text(out / "results.csv", buf.getvalue())
    tables = [out / "results.csv"]
    if _parquet(out / "results.parquet", columns, flat):
        tables.append(out / "results.parquet")
    n_ok = sum(r["status"] == "ok" for r in rows)
    n_failed = sum(r["status"] == "failed" for r in rows)
    n_not = len(rows) - n_ok - n_failed
    keys = columns[len(COLUMNS) :]
    head = ["job", "status", "attempts", "wall time (s)", "steps", "Newton its", "certified", "fill"]
    head += ["min distance", "deviation", *keys, "error"]
    lines = [
        f"# Batch {name}",
        "",
        f"{len(rows)} job(s): {n_ok} ok, {n_failed} failed"
        + (f", {n_not} not run" if n_not else "")
        + (f" ({len(skipped)} finished earlier, skipped)" if skipped else "")
        + f"; {wall:.1f} s on {cluster}.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
    ]
    for r in flat:
        cells = [r["job"], r["status"], r["attempts"], r["wall_time"], r["steps"], r["newton_iterations"]]
        cells += [r["all_certified"], r["fill_fraction"], r["min_distance"], r["deviation"]]
        cells += [r[k] for k in keys] + [r["error"]]
        lines.append("| " + " | ".join(_md_value(c) for c in cells) + " |")
    _write_text(out / "results.md", "\n".join(lines) + "\n")
    tables.append(out / "results.md")
    return tables
