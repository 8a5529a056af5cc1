"""The benchmark code path works end to end on a tiny generated scene (no timing is asserted)."""

import json

from idp.cli import main


def test_bench_tiny_scene_writes_json_table_and_plots(tmp_path, capsys):
    assert main(["bench", "--only", "tiny", "-o", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "tiny.json").read_text())
    for key in (
        "vertices",
        "tets",
        "steps",
        "wall_total",
        "wall_process",
        "newton_iterations",
        "newton_per_step",
        "per_iteration_split",
        "peak_rss_mb",
        "fill_final",
        "certified_frames",
    ):
        assert key in res
    assert res["steps"] == 3 and res["uncertified_frames"] == 0 and res["certified_frames"] == 3
    assert res["peak_rss_mb"] > 10
    # the machine it ran on, to compare runs across machines
    machine = res["machine"]
    assert machine["logical_cores"] >= 1 and machine["numba_target_cpu"]
    assert {"numpy", "scipy", "numba", "ipctk", "cvxopt", "cholmod"} <= set(machine["versions"])
    assert json.loads((tmp_path / "suite.json").read_text())["machine"]["versions"] == machine["versions"]
    split = res["per_iteration_split"]
    assert {"assembly", "linear_solve", "ccd", "line_search", "contact_build", "certificate", "other"} <= set(split)
    # the split partitions the step time (no phase counted twice): its parts add up to seconds per iteration
    steps_time = sum(split.values()) * res["newton_iterations"]
    assert abs(steps_time - sum(res["wall_per_step"])) <= 0.05 * sum(res["wall_per_step"]) + 1e-3
    table = (tmp_path / "results.md").read_text()
    assert "| tiny |" in table and "linear solve" in table
    assert table.startswith("**Machine:**") and "**numba:** target CPU" in table and "ipctk" in table
    assert (tmp_path / "fill_per_step.png").stat().st_size > 1000
    assert (tmp_path / "scaling.png").exists()


def test_bench_unknown_scene_is_an_error(tmp_path, capsys):
    assert main(["bench", "--only", "nope", "-o", str(tmp_path)]) == 2
    assert "nope" in capsys.readouterr().err


def test_bench_staged_scene_sums_its_stages(tmp_path, capsys):
    assert main(["bench", "--only", "tiny_stages", "-o", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "tiny_stages.json").read_text())
    assert [s["stage"] for s in res["stages"]] == ["grow", "settle"]
    assert [s["steps"] for s in res["stages"]] == [2, 1] and res["steps"] == 3
    assert res["newton_iterations"] == sum(s["newton_iterations"] for s in res["stages"]) == sum(res["newton_per_step"])
    assert res["certified_frames"] == 3 and res["uncertified_frames"] == 0
    assert abs(sum(res["per_iteration_split"].values()) * res["newton_iterations"] - res["wall_steps"]) <= (
        0.05 * res["wall_steps"] + 1e-3
    )
    assert "| tiny_stages |" in (tmp_path / "results.md").read_text()


def test_bench_solver_overrides_reach_the_run_and_are_recorded(tmp_path, capsys):
    assert main(["bench", "--only", "tiny", "-o", str(tmp_path), "--solver", "newton_tol=0.05"]) == 0
    res = json.loads((tmp_path / "tiny.json").read_text())
    assert res["solver_overrides"] == {"newton_tol": 0.05}
    assert json.loads((tmp_path / "suite.json").read_text())["solver_overrides"] == {"newton_tol": 0.05}
    # the tiny scene's own tolerance is 0.5: a tenfold tighter one must show in the recorded decrements
    stats = json.loads((tmp_path / "tiny" / "stats.json").read_text())
    finals = [r["newton_decrement"] for r in stats["steps"] if not r.get("initial")]
    assert finals and max(finals) <= 0.05


def test_bench_bad_solver_override_stops_before_any_run(tmp_path, capsys):
    for bad in ("contact_lookahead=0.5", "no_such_key=1", "newton_tol"):
        assert main(["bench", "--only", "tiny", "-o", str(tmp_path), "--solver", bad]) == 2
        err = capsys.readouterr().err
        assert "--solver" in err and bad.split("=")[0] in err
    assert not (tmp_path / "tiny.json").exists()
