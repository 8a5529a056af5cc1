"""`idp batch`: a spec of scenes, sweeps and repairs run as jobs on a local Dask cluster of 2 workers.

Properties: a bad spec (an unknown key path, an index past a list's end, a bad value) fails before anything runs,
naming the spec, the job and the key path; each job runs its own overridden scene in its own folder and reports a
certified summary; a job that fails at run time is retried the set number of times and reported with its error
while the others finish; a resumed batch skips the jobs that finished; a worker killed mid-job has its job run
again on another worker, resuming from its checkpoint, and the batch completes; the CLI's exit codes."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from idp.applications.batch import run_batch
from idp.cli import main
from idp.errors import SceneError
from idp.mesh.generate import ellipsoid_surface, tet_ball
from idp.mesh.io import write_mesh
from idp.output.stats import load_stats
from idp.scene.batch_schema import load_batch
from idp.scene.load import load_scene

#: the cluster tests need Dask (idp[batch]); the spec's and the serial CLI's do not
needs_dask = pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="needs idp[batch] (Dask)")

TINY = """
name = "tiny"
[time]
h = 0.0016
steps = {steps}
[solver]
newton_tol = 0.1
[contact]
dhat = 2e-3
dhat_mode = "relative"
[output]
png = false
obj = false
[[objects]]
name = "ball"
mesh = "ball.vtk"
rest_shape = {{ growth_rate = {rate}, growth_steps = {steps} }}
[[objects]]
name = "box"
kind = "obstacle"
generate = {{ shape = "box_surface", lo = [-0.45, -0.45, -0.45], hi = [0.45, 0.45, 0.45], resolution = 2 }}
"""

REPAIR = """
name = "spheres"
[contact]
dhat = 0.01
[repair]
input = "spheres.npz"
"""


def write_inputs(folder: Path) -> Path:
    """ball.vtk, tiny.toml (3 steps), slow.toml (600 short steps) and a repair scene of two spheres crossing."""
    folder.mkdir(parents=True, exist_ok=True)
    write_mesh(folder / "ball.vtk", tet_ball(0.3, resolution=2))
    (folder / "tiny.toml").write_text(TINY.format(steps=3, rate=0.2))
    (folder / "slow.toml").write_text(TINY.format(steps=600, rate=0.0013))
    s = ellipsoid_surface((0.3, 0.3, 0.3), subdivisions=1)
    n = s.vertices.shape[0]
    frames = []
    for g in (0.3, 0.0, -0.05, 0.3):  # the gap between the spheres: they cross in the third frame
        c = 0.3 + g / 2
        frames.append(np.vstack([s.vertices - np.array([c, 0.0, 0.0]), s.vertices + np.array([c, 0.01, 0.0])]))
    np.savez(folder / "spheres.npz", vertices=np.array(frames), faces=np.vstack([s.faces, s.faces + n]))
    (folder / "repair.toml").write_text(REPAIR)
    return folder


def write_spec(folder: Path, text: str, name: str = "spec.toml") -> Path:
    p = folder / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    folder = write_inputs(tmp_path_factory.mktemp("batch_inputs"))
    # compile (or load from numba's disk cache) the kernels once, here, rather than in every job's process
    for scene in ("tiny.toml", "repair.toml"):
        subprocess.run(
            [sys.executable, "-m", "idp", "run", str(folder / scene), "-o", str(folder / "warm" / scene), "-q"],
            check=True,
            capture_output=True,
        )
    return folder


# ---------------------------------------------------------------------------------------------
# The spec, checked before anything runs (no cluster)


def _error(tmp_path: Path, text: str) -> str:
    if not (tmp_path / "tiny.toml").exists():
        write_inputs(tmp_path)
    spec = write_spec(tmp_path, text)
    with pytest.raises(SceneError) as exc:
        load_batch(spec)
    return str(exc.value)


def test_an_unknown_key_path_is_named_with_its_job_before_anything_runs(tmp_path):
    msg = _error(
        tmp_path,
        '[base]\nscene = "tiny.toml"\n[grid]\n"objects[0].material.youngs_modulu" = [1e4]\n',
    )
    spec = str(tmp_path / "spec.toml")
    assert msg.startswith(spec) and "job youngs_modulu=10000" in msg
    assert "objects[0].material.youngs_modulu: unknown key (did you mean 'youngs_modulus'?)" in msg


def test_an_index_past_the_list_or_into_a_number_is_named(tmp_path):
    msg = _error(tmp_path, '[base]\nscene = "tiny.toml"\n[[cases]]\nname = "c"\nset = { "objects[2].scale" = 2.0 }\n')
    assert "job c (cases[0]): objects[2].scale: objects[2]: no such entry (objects has 2 entries" in msg
    msg = _error(tmp_path, '[base]\nscene = "tiny.toml"\n[grid]\n"time.steps.x" = [1]\n')
    assert "time.steps.x: time.steps is not a table in the scene (it is 3)" in msg


def test_bad_values_and_bad_key_paths_are_named(tmp_path):
    msg = _error(tmp_path, '[base]\nscene = "tiny.toml"\n[grid]\n"contact.dhat" = [1e-3, -1.0]\n')
    assert "job dhat=-1 (grid[1]): contact.dhat: must be > 0.0 (got -1.0)" in msg
    assert "dhat=0.001" not in msg  # the good job is not blamed
    msg = _error(tmp_path, '[base]\nscene = "tiny.toml"\n[grid]\n"contact..dhat" = [1e-3]\n')
    assert 'grid."contact..dhat": not a key path' in msg
    msg = _error(tmp_path, '[grid]\n"contact.dhat" = [1e-3]\n')
    assert "base: a [grid] needs a [base] table" in msg
    msg = _error(tmp_path, 'retry = 2\n[base]\nscene = "tiny.toml"\n[grid]\n"contact.dhat" = [1e-3]\n')
    assert "retry: unknown key (did you mean 'retries'?)" in msg
    msg = _error(tmp_path, '[[jobs]]\nscene = "nothere.toml"\n')
    assert "nothere.toml: cannot read scene file" in msg
    msg = _error(tmp_path, '[[jobs]]\nname = "a"\nscene = "tiny.toml"\n[[jobs]]\nname = "a"\nscene = "tiny.toml"\n')
    assert "job name 'a' is given to more than one case/job" in msg
    msg = _error(tmp_path, '[[jobs]]\nscene = "tiny.toml"\nset = { "objects[0].mesh" = "meshes/b.vtk" }\n')
    assert f"objects[0].mesh: file not found: {tmp_path / 'meshes' / 'b.vtk'}" in msg  # relative to the spec


def test_jobs_have_unique_safe_names_and_their_overrides(tmp_path):
    write_inputs(tmp_path)
    sub = tmp_path / "specs"
    sub.mkdir()
    spec = write_spec(
        sub,
        """
[base]
scene = "../tiny.toml"
[set]
time = { steps = 2 }
[grid]
"objects[0].material.youngs_modulus" = [1e4, 2e5]
"contact.dhat" = [2e-3, 0.0030000001, 0.003]
[[cases]]
set = { "objects[0].mesh" = "../ball.vtk" }
[[jobs]]
name = "repair"
scene = "../repair.toml"
""",
    )
    _, jobs = load_batch(spec)
    names = [j.name for j in jobs]
    assert len(jobs) == 8 and len(set(names)) == 8
    assert names[0] == "youngs_modulus=10000_dhat=0.002" and names[-2:] == ["mesh=ball", "repair"]
    assert names[1].startswith("youngs_modulus=10000_dhat=0.003-") and names[2].startswith(
        "youngs_modulus=10000_dhat=0.003-"
    )
    assert all(re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._=+-]*", n) for n in names)
    assert [j.name for j in load_batch(spec)[1]] == names  # deterministic
    for j in jobs[:6]:
        ob = j.scene.objects[0]
        assert (
            ob.material is not None and ob.material.youngs_modulus == j.overrides["objects[0].material.youngs_modulus"]
        )
        assert j.scene.contact.dhat == j.overrides["contact.dhat"] and j.scene.time.steps == 2
        again = load_scene(write_spec(tmp_path, j.scene_toml, f"{j.name}.toml"))  # the file a job runs
        assert again == j.scene
    assert jobs[6].scene.objects[0].mesh == (tmp_path / "ball.vtk").resolve()
    assert jobs[7].scene.repair is not None and jobs[7].scene.time.steps == 2


def test_a_job_gets_its_thread_counts_and_not_the_dask_workers_malloc_setting(monkeypatch):
    from idp.applications.batch import _job_env

    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")  # what Dask's nanny gives its workers
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    env = _job_env(2)
    assert "MALLOC_TRIM_THRESHOLD_" not in env  # it made every job a third slower
    assert all(env[v] == "2" for v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"))
    assert env["IDP_BATCH_PARENT"] == str(os.getpid())


# ---------------------------------------------------------------------------------------------
# A local cluster of 2 workers


def _rows(out: Path) -> dict[str, dict[str, str]]:
    with open(out / "results.csv", newline="") as fh:
        return {r["job"]: r for r in csv.DictReader(fh)}


@needs_dask
def test_a_sweep_with_a_failing_job_and_a_repair_on_two_workers_then_resumed(inputs, tmp_path):
    spec = write_spec(
        inputs,
        """
name = "sweep"
retries = 2
[base]
scene = "tiny.toml"
[grid]
"objects[0].material.youngs_modulus" = [1e4, 1e5]
[[cases]]
name = "crossing"        # the ball starts half through the box's wall: fails only when it runs
set = { "objects[0].translate" = [0.3, 0.0, 0.0] }
[[jobs]]
scene = "repair.toml"
""",
        "sweep.toml",
    )
    out = tmp_path / "out"
    workers: list[int] = []
    result = run_batch(
        spec, out, workers=2, progress=False, on_start=lambda c: workers.extend(c.run(os.getpid).values())
    )
    assert len(workers) == 2
    names = ["youngs_modulus=10000", "youngs_modulus=100000", "crossing", "repair"]
    assert [r["job"] for r in result.rows] == names
    rows = _rows(out)
    assert list(rows) == names
    for name, e in (("youngs_modulus=10000", 1e4), ("youngs_modulus=100000", 1e5)):
        r, d = rows[name], out / "jobs" / name
        assert r["status"] == "ok" and r["attempts"] == "1" and r["all_certified"] == "true" and r["steps"] == "3"
        assert float(r["objects[0].material.youngs_modulus"]) == e and float(r["wall_time"]) > 0
        assert int(r["newton_iterations"]) >= 3 and 0 < float(r["fill_fraction"]) < 1 and r["deviation"] == ""
        assert len(list((d / "run" / "vtu").glob("frame_*.vtu"))) == 4
        stats = load_stats(d / "run" / "stats.json")
        assert stats["summary"]["all_certified"] is True
        assert stats["meta"]["resolved_scene"]["objects"][0]["material"]["youngs_modulus"] == e
        assert load_scene(d / "scene.toml").objects[0].material.youngs_modulus == e
        rec = json.loads((d / "job.json").read_text())
        assert rec["status"] == "ok"
        assert rec["command"][3:] == ["run", "scene.toml", "-o", "run", "--resume", "-q", "--threads", "1"]
        assert {a["worker_pid"] for a in json.loads((d / "attempts.json").read_text())} <= set(workers)
    # the stiffness changes the run
    assert float(rows["youngs_modulus=100000"]["fill_fraction"]) != float(rows["youngs_modulus=10000"]["fill_fraction"])
    bad = rows["crossing"]
    assert bad["status"] == "failed" and bad["attempts"] == "3" and bad["exit_code"] == "2"
    assert "intersecting" in bad["error"] and bad["error"].startswith("exit code 2 (input error): idp: error:")
    attempts = json.loads((out / "jobs" / "crossing" / "attempts.json").read_text())
    assert [a["exit_code"] for a in attempts] == [2, 2, 2]
    assert not (out / "jobs" / "crossing" / "run" / "stats.json").exists()
    rep = rows["repair"]
    assert rep["status"] == "ok" and rep["all_certified"] == "true" and float(rep["deviation"]) >= 0
    assert (out / "jobs" / "repair" / "run" / "report.json").is_file()
    md = (out / "results.md").read_text()
    assert "4 job(s): 3 ok, 1 failed" in md and all(f"| {n} |" in md for n in names)
    pq = pytest.importorskip("pyarrow.parquet")
    table = pq.read_table(out / "results.parquet").to_pylist()
    assert [t["job"] for t in table] == names and table[0]["all_certified"] is True and table[2]["attempts"] == 3
    info = json.loads((out / "batch.json").read_text())
    assert info["status"] == "done" and [j["status"] for j in info["jobs"]] == ["ok", "ok", "failed", "ok"]

    # resumed: the finished jobs are skipped (their records untouched), the failed one runs again
    marks = {n: (out / "jobs" / n / "job.json").stat().st_mtime_ns for n in names}
    again = run_batch(spec, out, workers=2, retries=0, resume=True, progress=False)
    assert again.skipped == ["youngs_modulus=10000", "youngs_modulus=100000", "repair"]
    for n in again.skipped:
        assert (out / "jobs" / n / "job.json").stat().st_mtime_ns == marks[n]
        assert len(json.loads((out / "jobs" / n / "attempts.json").read_text())) == 1
    assert len(json.loads((out / "jobs" / "crossing" / "attempts.json").read_text())) == 4
    assert [r["status"] for r in again.rows] == ["ok", "ok", "failed", "ok"]
    assert _rows(out)["youngs_modulus=10000"]["wall_time"] == rows["youngs_modulus=10000"]["wall_time"]

    # the scene changed under a finished job: resuming it would continue another run, so it is refused
    (inputs / "tiny.toml").write_text(TINY.format(steps=4, rate=0.2))
    try:
        with pytest.raises(SceneError, match="hold runs of a different scene"):
            run_batch(spec, out, workers=2, resume=True, progress=False)
    finally:
        (inputs / "tiny.toml").write_text(TINY.format(steps=3, rate=0.2))


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True
    return "\nState:\tZ" not in state  # a zombie has ended


def _wait(cond, timeout: float, what: str, proc: subprocess.Popen | None = None) -> None:
    t0 = time.monotonic()
    while not cond():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the batch ended (exit {proc.returncode}) while waiting for {what}")
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


@needs_dask
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_worker_killed_mid_job_has_its_job_rerun_elsewhere(inputs, tmp_path):
    spec = write_spec(
        inputs,
        '[[jobs]]\nname = "slow"\nscene = "slow.toml"\n[[jobs]]\nname = "quick"\nscene = "tiny.toml"\n',
        "kill.toml",
    )
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "idp", "batch", str(spec), "-o", str(out), "--workers", "2", "--retries", "0", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        job = out / "jobs" / "slow"

        def first_attempt() -> dict | None:
            try:
                a = json.loads((job / "attempts.json").read_text())
            except (OSError, ValueError):
                return None
            return a[0] if a and "pid" in a[0] else None

        _wait(
            lambda: first_attempt() is not None and (job / "run" / "checkpoint.npz").exists(), 120, "a checkpoint", proc
        )
        a1 = first_attempt()
        assert a1 is not None
        os.kill(a1["pid"], signal.SIGSTOP)  # the job cannot finish now, whatever the timing
        assert not (job / "job.json").exists()
        os.kill(a1["worker_pid"], signal.SIGKILL)
        _wait(lambda: not _alive(a1["pid"]), 30, "the orphaned job to end with its worker")
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stdout + stderr
    assert "2: 2 ok, 0 failed" in stdout
    attempts = json.loads((job / "attempts.json").read_text())
    assert len(attempts) == 2 and attempts[0]["lost"] is True and attempts[1]["exit_code"] == 0
    assert attempts[1]["worker_pid"] != a1["worker_pid"]
    stats = load_stats(job / "run" / "stats.json")
    assert stats["summary"]["all_certified"] is True and stats["summary"]["last_step"] == 600
    resumes = stats["summary"].get("resumes", [])
    assert resumes and resumes[-1]["after_step"] > 0  # the re-run went on from the checkpoint, not from step 0
    assert [r["step"] for r in stats["steps"] if not r.get("initial")] == list(range(1, 601))
    assert _rows(out)["slow"]["attempts"] == "2"


@needs_dask
def test_a_batch_on_a_running_scheduler_given_by_address(inputs, tmp_path):
    from distributed import LocalCluster

    spec = write_spec(inputs, '[[jobs]]\nscene = "tiny.toml"\nset = { "time.steps" = 1 }\n', "remote.toml")
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None, silence_logs=50) as cluster:
        result = run_batch(spec, tmp_path / "out", scheduler=cluster.scheduler_address, progress=False)
        assert result.ok and cluster.scheduler_address in result.cluster
        assert len(cluster.workers) == 1  # its workers are still there: the batch closes only its own client
    rec = json.loads((tmp_path / "out" / "jobs" / "tiny_steps=1" / "job.json").read_text())
    assert rec["status"] == "ok" and rec["summary"]["steps"] == 1 and rec["worker"].startswith("tcp://")
    with pytest.raises(SceneError, match="give --workers or --scheduler"):
        run_batch(spec, tmp_path / "out", scheduler="tcp://127.0.0.1:1", workers=2)


# ---------------------------------------------------------------------------------------------
# The CLI


def test_cli_exit_codes_summary_and_missing_dask(inputs, tmp_path, capsys, monkeypatch):
    good = write_spec(inputs, '[[jobs]]\nscene = "tiny.toml"\nset = { "time.steps" = 1 }\n', "good.toml")
    assert main(["batch", str(good), "-o", str(tmp_path / "g"), "--serial"]) == 0
    printed, bar = capsys.readouterr()
    assert "done=1" in bar and "failed=0" in bar and "1/1" in bar  # the progress bar's last state
    assert "1: 1 ok, 0 failed" in printed and "serial" in printed and str(tmp_path / "g" / "results.md") in printed
    bad = write_spec(
        inputs,
        '[[jobs]]\nscene = "tiny.toml"\nset = { "time.steps" = 1 }\n'
        '[[jobs]]\nname = "x"\nscene = "tiny.toml"\nset = { "objects[0].translate" = [0.3, 0.0, 0.0] }\n',
        "bad.toml",
    )
    assert main(["batch", str(bad), "-o", str(tmp_path / "b"), "--serial", "--retries", "1", "-q"]) == 4
    printed = capsys.readouterr().out
    assert "2: 1 ok, 1 failed" in printed and "FAILED:   x after 2 attempt(s): exit code 2" in printed
    typo = write_spec(inputs, '[[jobs]]\nscene = "tiny.toml"\nset = { "time.step" = 1 }\n', "typo.toml")
    assert main(["batch", str(typo), "-o", str(tmp_path / "t"), "--serial"]) == 2
    err = capsys.readouterr().err
    assert f"idp: error: {typo}: job tiny_step=1 (jobs[0]): time.step: unknown key (did you mean 'steps'?)" in err
    assert "Traceback" not in err and not (tmp_path / "t").exists()
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if Dask were not installed
    assert main(["batch", str(good), "-o", str(tmp_path / "n")]) == 2
    assert "pip install 'idp[batch]'" in capsys.readouterr().err
