"""Memory and time guards of a run: solver.max_memory / --max-memory, solver.max_step_seconds / --max-step-seconds,
solver.max_newton_iterations / --max-newton-iterations."""

import json
import logging

import pytest
from test_cli import write_scene  # type: ignore[import-not-found]

from idp.api import simulate
from idp.cli import EXIT_SOLVER, main
from idp.errors import ResourceError
from idp.scene.build import build_scene
from idp.scene.load import load_scene
from idp.solver.linear import have_pymetis, make_linear_solver
from idp.stepper.run import run_simulation

needs_ordering = pytest.mark.skipif(
    not have_pymetis(), reason="the memory estimate needs the solver's ordering beforehand (pymetis)"
)


def _steps(out):
    return json.loads((out / "stats.json").read_text())["steps"]


@needs_ordering
def test_tiny_max_memory_stops_before_any_step(tmp_path, capsys):
    scene = write_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(scene), "-o", str(out), "-q", "--max-memory", "1M"]) == EXIT_SOLVER
    err = capsys.readouterr().err
    assert "not enough memory: the step needs about" in err
    assert "DOFs" in err and "but the limit is 1 MiB" in err and "coarser mesh" in err and "--max-memory" in err
    # step 0 (the certified input) is written; nothing after it
    assert [p.name for p in sorted((out / "obj").glob("*.obj"))] == ["frame_00000.obj"]
    steps = _steps(out)
    assert len(steps) == 1 and steps[0]["initial"]
    assert not (out / "checkpoint.npz").exists()


@needs_ordering
def test_memory_error_comes_before_the_first_factorisation(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    scene.solver = scene.solver.model_copy(update={"max_memory": "1M"})
    built = build_scene(scene)
    linear = make_linear_solver("auto", dofs_per_node=3)
    with pytest.raises(ResourceError, match=r"limit is 1 MiB \(solver\.max_memory\)"):
        run_simulation(built.system, built.newton, linear, built.certifier, tmp_path / "o", built.run)
    assert linear.stats["factorizations"] == 0
    assert linear.memory_guard is not None and linear.memory_guard.last is not None


def test_scene_key_max_memory_and_a_generous_limit_run_normally(tmp_path):
    scene = write_scene(tmp_path)
    text = scene.read_text().replace("newton_tol = 0.1\n", 'newton_tol = 0.1\nmax_memory = "64G"\n')
    scene.write_text(text)
    out = tmp_path / "out"
    result = simulate(load_scene(scene), out, progress=False)
    assert result.summary["all_certified"] and result.summary["steps_run"] == 3
    resolved = json.loads((out / "scene.resolved.json").read_text())
    assert resolved["solver"]["max_memory"] == "64G"
    if have_pymetis():
        est = result.summary["memory_estimate"]
        assert 0 < est["total_bytes"] < 64 << 30 and est["factor_nonzeros"] >= est["dofs"]


@pytest.mark.parametrize("value", ['"lots"', "0", "-1", '"4X"', "true"])
def test_bad_max_memory_in_a_scene_names_the_key(tmp_path, capsys, value):
    scene = write_scene(tmp_path)
    scene.write_text(scene.read_text().replace("newton_tol = 0.1\n", f"newton_tol = 0.1\nmax_memory = {value}\n"))
    assert main(["run", str(scene), "-o", str(tmp_path / "o"), "-q"]) == 2
    assert "solver.max_memory" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "value"),
    [("--max-memory", "lots"), ("--max-memory", "0"), ("--max-step-seconds", "0"), ("--max-newton-iterations", "0")],
)
def test_bad_limits_on_the_command_line(tmp_path, capsys, flag, value):
    scene = write_scene(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(["run", str(scene), "-q", flag, value])
    assert info.value.code == 2
    assert flag in capsys.readouterr().err


def test_wall_limit_ends_each_step_after_one_certified_iterate(tmp_path, caplog):
    scene = write_scene(tmp_path)
    scene.write_text(scene.read_text().replace("newton_tol = 0.1\n", "newton_tol = 1e-6\nmax_step_seconds = 1e-9\n"))
    with caplog.at_level(logging.WARNING, logger="idp"):
        result = simulate(load_scene(scene), tmp_path / "out", progress=False)
    recs = result.step_records
    assert len(recs) == 3 and result.summary["all_certified"]
    for r in recs:
        assert r["newton_iterations"] == 1
        assert r["hit_wall_limit"] and not r["converged"] and not r["hit_iteration_cap"]
        assert r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"]
    assert result.summary["nonconverged_steps"] == 3
    assert "hit the wall-clock limit solver.max_step_seconds = 1e-09 s after 1 Newton iteration" in caplog.text


def test_wall_limit_with_on_nonconvergence_error_exits_4(tmp_path, capsys):
    scene = write_scene(tmp_path)
    scene.write_text(
        scene.read_text().replace("newton_tol = 0.1\n", 'newton_tol = 1e-6\non_nonconvergence = "error"\n')
    )
    out = tmp_path / "out"
    assert main(["run", str(scene), "-o", str(out), "-q", "--max-step-seconds", "1e-9"]) == EXIT_SOLVER
    err = capsys.readouterr().err
    assert "step 1 did not converge (hit the wall-clock limit solver.max_step_seconds = 1e-09 s" in err
    steps = _steps(out)
    assert [s["step"] for s in steps] == [0, 1]
    assert steps[1]["hit_wall_limit"] and steps[1]["newton_iterations"] == 1
    assert steps[1]["certificate"]["intersection_free"] and steps[1]["certificate"]["inversion_free"]
    # the certified state of the stopped step is kept (frame and checkpoint), so the run can be resumed
    assert (out / "obj" / "frame_00001.obj").exists() and (out / "checkpoint.npz").exists()
    resolved = json.loads((out / "scene.resolved.json").read_text())
    assert resolved["solver"]["max_step_seconds"] == 1e-9


def test_max_newton_iterations_on_the_command_line(tmp_path, capsys):
    scene = write_scene(tmp_path)
    scene.write_text(scene.read_text().replace("newton_tol = 0.1\n", "newton_tol = 1e-6\n"))
    out = tmp_path / "out"
    assert main(["run", str(scene), "-o", str(out), "-q", "--max-newton-iterations", "1"]) == 0
    steps = _steps(out)[1:]
    assert all(s["newton_iterations"] == 1 and s["hit_iteration_cap"] and not s["hit_wall_limit"] for s in steps)
    assert json.loads((out / "scene.resolved.json").read_text())["solver"]["max_newton_iterations"] == 1
    assert "3 step(s) not converged" in capsys.readouterr().out
