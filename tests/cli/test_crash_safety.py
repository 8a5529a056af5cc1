"""Crash safety, proven by killing runs (issue 15): ``idp run`` processes killed with SIGKILL at the most harmful
points (``IDP_KILL_AT``, :mod:`idp._faults`) and at random moments, stopped with SIGTERM, then resumed with
``--resume``, must end with the very bytes of an uninterrupted run (frames, PVD, picture) and the same
statistics (wall times aside), and must never leave a file a reader would take for a frame. Staged (modeling)
runs the same; animation repair: tests/applications/test_repair.py. A resume with a changed scene is refused."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from idp.cli import demo_scene_path

pytestmark = pytest.mark.slow

STEPS = 8  # the demo scene (a ball grown into an hourglass cage, in contact from the first steps), 8 steps
# the processes must do the same arithmetic: the same thread count for all of them (any count will do)
ENV = {**os.environ, "NUMBA_NUM_THREADS": "2", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
ENV.pop("IDP_KILL_AT", None)
TIMING_KEYS = {"wall_time", "timings", "linear_solver", "resumes", "memory_estimate"}


def _cmd(scene: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "idp", "run", str(scene), "-o", str(out), "--steps", str(STEPS), "-q", *extra]


def _run(scene: Path, out: Path, *extra: str, kill_at: str | None = None) -> subprocess.CompletedProcess:
    env = dict(ENV, IDP_KILL_AT=kill_at) if kill_at else ENV
    return subprocess.run(_cmd(scene, out, *extra), env=env, capture_output=True, text=True, timeout=300)


def _outputs(out: Path) -> dict[str, bytes]:
    """Every output a reader looks at: the frames (OBJ, VTU), the PVD series and the picture."""
    files = [*out.glob("obj/*.obj"), *out.glob("vtu/*.vtu"), out / "frames.pvd", out / "frames.png"]
    return {str(f.relative_to(out)): f.read_bytes() for f in files if f.is_file()}


def _without_timings(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if k not in TIMING_KEYS}
    if isinstance(obj, list):
        return [_without_timings(v) for v in obj]
    return obj


def _stats(out: Path) -> dict:
    stats = json.loads((out / "stats.json").read_text())
    stats["meta"].pop("resolved_scene", None)  # holds output.dir, which differs between the folders
    return _without_timings(stats)


def _leftovers(out: Path) -> list[str]:
    return [str(p.relative_to(out)) for p in out.rglob("*") if ".tmp" in p.name]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[Path, dict[str, bytes], dict]:
    out = tmp_path_factory.mktemp("crash") / "uninterrupted"
    r = _run(demo_scene_path(), out)
    assert r.returncode == 0, r.stderr
    outputs = _outputs(out)
    assert sum(name.startswith("vtu/") for name in outputs) == STEPS + 1
    return out, outputs, _stats(out)


def _assert_same_as_reference(out: Path, reference, resumes: int | None = None) -> None:
    _, ref_outputs, ref_stats = reference
    outputs = _outputs(out)
    assert sorted(outputs) == sorted(ref_outputs)
    differing = [name for name in outputs if outputs[name] != ref_outputs[name]]
    assert not differing, f"differ from the uninterrupted run: {differing}"
    assert _stats(out) == ref_stats
    assert not _leftovers(out)
    summary = json.loads((out / "stats.json").read_text())["summary"]
    if resumes is not None:
        assert len(summary.get("resumes", [])) == resumes
    assert summary["steps_run"] == STEPS and summary["all_certified"]


def _assert_only_whole_frames(out: Path, reference) -> None:
    """After a kill: each frame file that exists is the uninterrupted run's frame, byte for byte (a torn write
    only ever leaves a ``.tmp`` file, which no reader takes for a frame); the checkpoint and stats are whole."""
    _, ref_outputs, _ = reference
    for name, data in _outputs(out).items():
        if name.startswith(("obj/", "vtu/")):
            assert data == ref_outputs[name], f"{name} left by the killed run is not the finished frame"
    if (out / "checkpoint.npz").exists():
        with np.load(out / "checkpoint.npz") as ck:
            assert 0 <= int(ck["step"]) <= STEPS
    if (out / "stats.json").exists():
        json.loads((out / "stats.json").read_text())


@pytest.mark.parametrize(
    "kill_at",
    [
        "newton:9",  # inside a Newton step (after an accepted iterate)
        "frame_tmp:5",  # a frame written to its temporary name, not yet renamed
        "frame_between:3",  # a frame's OBJ in place, its VTU not yet written
        "pvd:4",  # the PVD index written to its temporary name
        "checkpoint:4",  # the checkpoint written to its temporary name
        "stats:6",  # stats.json written to its temporary name
    ],
)
def test_a_run_killed_at_a_harmful_point_resumes_to_the_uninterrupted_bytes(tmp_path, reference, kill_at):
    out = tmp_path / "killed"
    killed = _run(demo_scene_path(), out, kill_at=kill_at)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    _assert_only_whole_frames(out, reference)
    resumed = _run(demo_scene_path(), out, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    _assert_same_as_reference(out, reference, resumes=1)


def test_a_run_killed_at_random_moments_again_and_again_resumes_to_the_same_bytes(tmp_path, reference):
    out = tmp_path / "random"
    rng = random.Random(15)
    kills = 0
    for attempt in range(4):
        proc = subprocess.Popen(
            _cmd(demo_scene_path(), out, *(["--resume"] if attempt else [])),
            env=ENV,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            proc.wait(timeout=rng.uniform(0.8, 2.5))  # the interpreter starts in ~1 s, a step takes ~0.1 s
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            kills += 1
            _assert_only_whole_frames(out, reference)
    final = _run(demo_scene_path(), out, "--resume")
    assert final.returncode == 0, final.stderr
    _assert_same_as_reference(out, reference)
    assert kills >= 1  # otherwise this test proved nothing (it runs on any machine speed: most attempts kill)


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if path.exists():
            return True
        time.sleep(0.01)
    return False


def test_sigterm_stops_cleanly_with_exit_130_and_the_run_resumes(tmp_path, reference):
    out = tmp_path / "term"
    proc = subprocess.Popen(_cmd(demo_scene_path(), out), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if not _wait_for(out / "vtu" / "frame_00002.vtu", proc):
        proc.kill()
        pytest.skip("the run ended before it could be stopped")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before SIGTERM arrived")
    assert proc.returncode == 130, err
    assert b"terminated (SIGTERM)" in err and b"Traceback" not in err
    summary = json.loads((out / "stats.json").read_text())["summary"]
    assert summary["stopped"].startswith("interrupted")
    _assert_only_whole_frames(out, reference)
    resumed = _run(demo_scene_path(), out, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    _assert_same_as_reference(out, reference, resumes=1)


def test_a_resume_killed_right_after_it_started_keeps_the_finished_steps_stats(tmp_path, reference):
    """A resumed run rewrites stats.json at once: the finished steps' records must be in that first write (they
    were re-added one write at a time, so a resume killed at its second write left a file without them, and the
    next resume started its statistics afresh: found by the random-kill test on a loaded machine)."""
    out = tmp_path / "twice"
    killed = _run(demo_scene_path(), out, kill_at="checkpoint:5")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    with np.load(out / "checkpoint.npz") as ck:
        done = int(ck["step"])  # the steps a resume keeps (a later record, without its checkpoint, is redone)
    kept = [r for r in json.loads((out / "stats.json").read_text())["steps"] if not r.get("initial")][:done]
    assert done >= 3 and [r["step"] for r in kept] == list(range(1, done + 1))
    again = _run(demo_scene_path(), out, "--resume", kill_at="stats:2")  # its first write done, its second torn
    assert again.returncode == -signal.SIGKILL, again.stderr
    after = [r for r in json.loads((out / "stats.json").read_text())["steps"] if not r.get("initial")]
    assert [r["step"] for r in after][: len(kept)] == [r["step"] for r in kept]
    final = _run(demo_scene_path(), out, "--resume")
    assert final.returncode == 0, final.stderr
    _assert_same_as_reference(out, reference)


@pytest.mark.parametrize("delay", [0.05, 0.4, 1.2, 2.5])
def test_sigterm_at_any_moment_exits_130_without_a_traceback(tmp_path, delay):
    """During start-up (imports, scene reading, kernel loads) or during the steps — before issue 16's fix a
    SIGTERM could surface inside numba's or pydantic's glue as a SystemError, a RuntimeError or a crash."""
    cmd = [sys.executable, "-m", "idp", "run", str(demo_scene_path()), "-o", str(tmp_path / "out"), "-q"]  # 80 steps
    proc = subprocess.Popen(cmd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    time.sleep(delay)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before SIGTERM arrived")
    if proc.returncode == -signal.SIGTERM:  # arrived before the interpreter had run idp's code (a loaded machine)
        assert delay < 0.2 and not err, err
        return
    assert proc.returncode == 130, err
    assert b"Traceback" not in err and b"terminated (SIGTERM)" in err, err


def test_a_resume_with_a_changed_scene_is_refused_naming_the_keys_unless_forced(tmp_path):
    text = demo_scene_path().read_text()
    original, changed = tmp_path / "scene.toml", tmp_path / "changed.toml"
    original.write_text(text)
    assert "youngs_modulus = 1e4" in text and "dhat = 1e-3" in text
    changed.write_text(
        text.replace("youngs_modulus = 1e4", "youngs_modulus = 2e4").replace("dhat = 1e-3", "dhat = 2e-3")
    )
    out = tmp_path / "out"
    first = subprocess.run([*_cmd(original, out)[:-3], "--steps", "2", "-q"], env=ENV, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    before = (out / "checkpoint.npz").read_bytes()
    refused = _run(changed, out, "--resume")
    assert refused.returncode == 2
    assert "objects[0].material.youngs_modulus" in refused.stderr and "contact.dhat" in refused.stderr
    assert "--force" in refused.stderr and "Traceback" not in refused.stderr
    assert (out / "checkpoint.npz").read_bytes() == before  # nothing was touched
    # the step count may change (a resume that runs further); the same scene resumes
    longer = tmp_path / "longer.toml"
    longer.write_text(text.replace("steps = 80", "steps = 90"))
    assert _run(longer, out, "--resume").returncode == 0
    forced = _run(changed, out, "--resume", "--force")
    assert forced.returncode == 0, forced.stderr


STAGED = {
    "name": "two",
    "dim": 3,
    "gravity": [0.0, -9.8, 0.0],
    "contact": {"dhat": 1e-3},
    "objects": [
        {
            "name": "dough",
            "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
            "translate": [0.0, 0.32, 0.0],
            "material": {"youngs_modulus": 2e3},
            "plasticity": {"yield_stress": 50.0},
        },
        {
            "name": "floor",
            "kind": "obstacle",
            "generate": {"shape": "box_surface", "lo": [-1, -0.1, -1], "hi": [1, 0.0, 1], "resolution": 2},
        },
    ],
    "stages": [
        {"name": "drop", "steps": 3, "after": {"dough": "bake"}},
        {"name": "settle", "steps": 3, "set": {"dough": {"material": {"youngs_modulus": 3e3}}}},
    ],
}


def _staged_outputs(out: Path) -> dict[str, bytes]:
    files = [p for p in out.rglob("*") if p.is_file() and p.suffix in (".obj", ".vtu", ".pvd", ".png", ".npz")]
    return {str(f.relative_to(out)): f.read_bytes() for f in files if f.name != "checkpoint.npz"}


@pytest.mark.parametrize("kill_at", ["stage:1", "checkpoint:5", "newton:12"])
def test_a_killed_staged_run_resumes_to_the_uninterrupted_bytes(tmp_path, kill_at):
    scene = tmp_path / "staged.json"
    scene.write_text(json.dumps(STAGED))

    def run(out: Path, *extra: str, kill: str | None = None) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "idp", "run", str(scene), "-o", str(out), "-q", *extra]
        env = dict(ENV, IDP_KILL_AT=kill) if kill else ENV
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)

    assert run(tmp_path / "whole").returncode == 0
    killed = run(tmp_path / "killed", kill=kill_at)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    resumed = run(tmp_path / "killed", "--resume")
    assert resumed.returncode == 0, resumed.stderr
    whole, again = _staged_outputs(tmp_path / "whole"), _staged_outputs(tmp_path / "killed")
    assert sorted(again) == sorted(whole) and any(name.startswith("final/") for name in whole)
    assert [name for name in whole if whole[name] != again[name]] == []
    assert not _leftovers(tmp_path / "killed")


def _disk_in_ring_2d(steps: int) -> dict:
    """A 2D disk grown against a fixed ring (tests/scenes/): ipctk evaluates the barrier (2D has no compiled path)."""
    doc = json.loads((Path(__file__).parents[1] / "scenes" / "disk_in_ring_2d.json").read_text())
    doc["time"]["steps"] = doc["objects"][0]["rest_shape"]["growth_steps"] = steps
    return doc


def test_a_killed_2d_contact_run_resumes_to_the_uninterrupted_bytes(tmp_path):
    """ipctk builds the 2D collision set and sums the barrier; on its threads the last bits followed the schedule
    (3 of 4 runs killed and resumed like this ended with other bytes) until those calls ran on one thread
    (idp.contact.model.one_ipctk_thread)."""
    scene = tmp_path / "disk.json"
    scene.write_text(json.dumps(_disk_in_ring_2d(12)))

    def run(out: Path, *extra: str, kill: str | None = None) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "idp", "run", str(scene), "-o", str(out), "-q", "--threads", "2", *extra]
        env = dict(ENV, IDP_KILL_AT=kill) if kill else ENV
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)

    assert run(tmp_path / "whole").returncode == 0
    whole_stats = _stats(tmp_path / "whole")
    assert max(s.get("contacts", 0) for s in whole_stats["steps"]) > 0  # the disk meets the ring
    killed = run(tmp_path / "killed", kill="newton:40")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert run(tmp_path / "killed", "--resume").returncode == 0
    whole, again = _outputs(tmp_path / "whole"), _outputs(tmp_path / "killed")
    assert sorted(again) == sorted(whole) and len(whole) >= 12
    assert [name for name in whole if whole[name] != again[name]] == []
    assert _stats(tmp_path / "killed") == whole_stats
