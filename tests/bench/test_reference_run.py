"""`idp bench --with-reference`: reading the reference's output, pairing runs, and the report (no time asserted).

A stand-in ``run.sh`` (written here) prints the same lines as the authors' wrapper, so the whole code path runs
everywhere; one test runs the real reference on bunny_700 when it and the paper's data are present."""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
from pathlib import Path

import pytest

import idp.bench.suite as suite
from idp.bench.data import find_data_dir
from idp.bench.reference_run import (
    ReferenceCase,
    compare,
    find_reference,
    parse_ref_output,
    parse_timing_tree,
    reference_split,
    run_measured,
)
from idp.cli import main

RED, END = "\x1b[22;31m", "\x1b[0m"


def _tree_log(scale: float = 1.0) -> str:
    """A log in the authors' format: per-frame lines, then the cumulative tree (last Global block wins)."""

    def node(prefix: str, name: str, seconds: float) -> str:
        seconds *= scale
        text = f"{seconds:.6f}s" if seconds < 60 else f"{int(seconds // 60)}m {seconds % 60:.6f}s"  # as it prints
        return f"{prefix} {name} : 0.001s (1.0%%)   {RED}{text} (10.0%%){END}"

    return "\n".join(
        [
            "Total PN iteration count:  10 ",
            node("┏", "Global", 1.0),  # an earlier, superseded tree
            "┗",
            "Advance dt with 4.00e-02",
            node("┏", "Global", 10.0),
            node("┃", "Write_Surface_TriMesh_Obj", 0.5),
            node("┃┏", "implicitEuler_drdx_ipc", 9.0),
            node("┃┃", "Find Object Boundary", 0.5),
            node("┃┃┏", "Compute_Intersection_Free_StepSize", 2.0),
            node("┃┃┃", "Compute_Intersection_Free_StepSize_EE", 1.5),
            node("┃┃┃", "Uncounted", 0.5),
            "┃┃┗",
            node("┃┃┏", "Compute_Constraint_Set", 1.0),
            node("┃┃┃", "Compute_Constraint_Set_PT", 1.0),
            "┃┃┗",
            node("┃┃", "Compute_IncPotential", 0.25),
            node("┃┃┏", "Compute_IncPotential_Hessian", 1.5),
            node("┃┃┃", "Compute_Barrier_Hessian", 1.0),
            "┃┃┗",
            node("┃┃", "constructCSRMatrixFromTriplet", 0.5),
            node("┃┃", "linearSolve", 3.0),
            node("┃┃", "Uncounted", 0.25),
            "┃┗",
            node("┃", "Uncounted", 0.5),
            "┗",
            "",
            "DRIVER final: done",
        ]
    )


def test_timing_tree_is_read_with_depths_from_the_last_global_block():
    tree = parse_timing_tree(_tree_log())
    assert tree[0] == (1, "Global", 10.0)
    names = {name: (depth, sec) for depth, name, sec in tree}
    assert names["implicitEuler_drdx_ipc"] == (2, 9.0)
    assert names["Write_Surface_TriMesh_Obj"] == (2, 0.5)
    assert names["Compute_Intersection_Free_StepSize"] == (3, 2.0)
    assert names["Compute_Intersection_Free_StepSize_EE"] == (4, 1.5)
    assert names["linearSolve"] == (3, 3.0)
    assert parse_timing_tree("no tree here") == []


def test_timer_values_over_a_minute_are_read_in_seconds():
    tree = parse_timing_tree(_tree_log(scale=20.0))  # Global: 200 s, printed "3m 20.000000s"
    assert tree[0] == (1, "Global", pytest.approx(200.0))
    names = {name: sec for _, name, sec in tree}
    assert names["linearSolve"] == pytest.approx(60.0) and names["implicitEuler_drdx_ipc"] == pytest.approx(180.0)
    h = "┏ Global : 0.1s (100.0%%)   " + RED + "1h 2m 3.5s (100.0%%)" + END
    assert parse_timing_tree(h)[0][2] == pytest.approx(3723.5)


def test_reference_split_groups_the_solver_children_per_newton_iteration():
    split = reference_split(parse_timing_tree(_tree_log()), newton_iterations=10)
    assert split["linear_solve"] == pytest.approx(0.3)
    assert split["ccd"] == pytest.approx(0.2)
    assert split["contact_build"] == pytest.approx(0.15)  # constraint set + object boundary
    assert split["assembly"] == pytest.approx(0.2)  # Hessian + CSR construction (nested nodes not counted twice)
    assert split["line_search"] == pytest.approx(0.025)
    # the groups and "other" partition the solver node; the frame writes are outside it
    assert sum(v for k, v in split.items() if k != "outside_solver") == pytest.approx(0.9)
    assert split["outside_solver"] == pytest.approx(0.1)
    assert reference_split([], 10) == {}


def test_ref_lines_are_parsed_and_a_missing_final_line_is_an_error():
    out = (
        "DRIVER something\n"
        "REF_STEP step=1 newton_its=5 wall_s=0.5 tet_volume=1.25\n"
        "REF_STEP step=2 newton_its=2 wall_s=0.2 tet_volume=1.5\n"
        "REF scene=bunny args=0,1,10000,20 wall_s=14.30 newton_its=7 steps=2 tet_volume=1.5 "
        "min_tet_volume=6.1e-05 peak_rss_mb=99.6\n"
    )
    ref = parse_ref_output(out)
    assert ref["wall_s"] == 14.30 and ref["newton_its"] == 7 and ref["args"] == "0,1,10000,20"
    assert [s["newton_its"] for s in ref["per_step"]] == [5, 2]
    with pytest.raises(ValueError, match="REF"):
        parse_ref_output("REF_STEP step=1 newton_its=5\n")


def test_compare_pairs_runs_and_takes_medians():
    idp_runs = [
        {"wall_process": w, "newton_iterations": 50, "fill_final": 0.9, "peak_rss_mb": m}
        for w, m in ((2.0, 200), (4.0, 210), (3.0, 205))
    ]
    ref_runs = [{"wall_s": w, "newton_its": 48, "tet_volume": 4.0, "peak_rss_mb": 90} for w in (10.0, 8.0, 9.0)]
    c = compare(idp_runs, ref_runs, cage_volume=8.0)
    assert c["runs"] == 3 and c["speedup"] == pytest.approx(9.0 / 3.0)
    assert c["speedup_per_run"] == pytest.approx([5.0, 2.0, 3.0]) and c["speedup_spread"] == pytest.approx([2, 5])
    assert c["reference_fill"] == pytest.approx(0.5) and c["idp_peak_rss_mb"] == 210
    assert compare(idp_runs, ref_runs, cage_volume=None)["reference_fill"] is None


FAKE_RUN_SH = """#!/bin/bash
# stand-in for the reference's run.sh: the same output lines, a timing tree in $REF_RUN_DIR/run.log
echo "$@" >> "$(dirname "$0")/calls.txt"
n=$(wc -l < "$(dirname "$0")/calls.txt")
cp "$(dirname "$0")/tree.log" "$REF_RUN_DIR/run.log"
mkdir -p "$REF_RUN_DIR/Projects/FEM/scripts/output"
echo "REF_STEP step=1 newton_its=4 wall_s=0.1 tet_volume=0.2"
echo "REF scene=$1 args=$2 wall_s=$((n * 10)).0 newton_its=10 steps=3 tet_volume=0.36 peak_rss_mb=90"
"""


@pytest.fixture
def fake_reference(tmp_path, monkeypatch):
    ref = tmp_path / "fake_reference"
    ref.mkdir()
    (ref / "run.sh").write_text(FAKE_RUN_SH)
    (ref / "run.sh").chmod(0o755)
    (ref / "tree.log").write_text(_tree_log())
    monkeypatch.setenv("IDP_REFERENCE", str(ref))
    monkeypatch.setitem(suite.REFERENCE_CASES, "tiny", ReferenceCase("bunny", ("0",)))
    return ref


def test_with_reference_alternates_runs_and_reports_same_run_ratios(tmp_path, fake_reference, capsys):
    assert find_reference() == fake_reference.resolve()
    out = tmp_path / "out"
    assert main(["bench", "--only", "tiny", "--with-reference", "--runs", "2", "-o", str(out)]) == 0
    # two reference runs, each after an idp run, with the case's arguments
    assert (fake_reference / "calls.txt").read_text().splitlines() == ["bunny 0", "bunny 0"]
    c = json.loads((out / "tiny.reference.json").read_text())
    assert c["runs"] == 2 and c["reference_walls"] == [10.0, 20.0]
    assert c["speedup"] == pytest.approx(15.0 / statistics.median(c["idp_walls"]))
    assert c["speedup_per_run"] == pytest.approx([10.0 / c["idp_walls"][0], 20.0 / c["idp_walls"][1]])
    res = json.loads((out / "tiny.json").read_text())
    assert c["reference_fill"] == pytest.approx(0.36 / res["cage_volume"])  # the reference's volume / our cage
    assert c["reference_split"]["linear_solve"] == pytest.approx(0.3)
    # only the log is kept of a reference run (the authors' frames are removed)
    kept = sorted(p.name for p in (out / "reference" / "tiny" / "run2").iterdir())
    assert kept == ["run.log", "stdout.txt"]
    table = (out / "results.md").read_text()
    assert "Same machine, same run" in table and "| tiny | 2 |" in table and "| tiny | reference |" in table
    suite_json = json.loads((out / "suite.json").read_text())
    assert suite_json["with_reference"]["tiny"]["runs"] == 2


def test_without_the_reference_the_bench_runs_and_says_the_ratio_is_unavailable(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(suite, "find_reference", lambda *a: None)
    monkeypatch.setitem(suite.REFERENCE_CASES, "tiny", ReferenceCase("bunny", ("0",)))
    assert main(["bench", "--only", "tiny", "--with-reference", "-o", str(tmp_path)]) == 0
    assert "reference code was not found" in capsys.readouterr().err
    table = (tmp_path / "results.md").read_text()
    assert "reference not found" in table and "×" not in table.split("idp per scene")[0]


def test_a_failing_reference_run_is_reported_not_raised(tmp_path, fake_reference, capsys):
    (fake_reference / "run.sh").write_text("#!/bin/bash\necho 'reference: mesh missing' >&2\nexit 2\n")
    assert main(["bench", "--only", "tiny", "--with-reference", "-o", str(tmp_path)]) == 0
    assert "mesh missing" in capsys.readouterr().err
    assert "reference run failed" in (tmp_path / "results.md").read_text()


def _real_reference() -> Path | None:
    data = find_data_dir()
    ref = find_reference(data)
    if data is None or ref is None or shutil.which("ldd") is None:
        return None
    libs = subprocess.run(["ldd", *map(str, (ref / "lib").glob("JGSL*.so"))], capture_output=True, text=True)
    if libs.returncode != 0 or "not found" in libs.stdout or "avx2" not in Path("/proc/cpuinfo").read_text():
        return None
    return ref


@pytest.mark.slow
@pytest.mark.data
def test_the_real_reference_runs_beside_idp_on_bunny_700(tmp_path, monkeypatch):
    ref = _real_reference()
    if ref is None:
        pytest.skip("the prebuilt reference (../shared/reference, set up with its setup.sh) or the data is absent")
    monkeypatch.setenv("IDP_REFERENCE", str(ref))
    monkeypatch.setenv("OMP_NUM_THREADS", os.environ.get("OMP_NUM_THREADS", "2"))
    assert main(["bench", "--only", "bunny_700", "--with-reference", "--runs", "1", "-o", str(tmp_path)]) == 0
    c = json.loads((tmp_path / "bunny_700.reference.json").read_text())
    # its README's figures for this case (236 iterations, volume 7.81414958 of the box's 8) on an idle machine; under
    # load its OpenMP reductions may run in another order (measured: 237, and 225 on an Intel Xeon with other jobs
    # beside it), so the iterations are checked within 10 %, the fill tightly
    assert abs(c["reference_newton_iterations"] - 236) <= 24 and c["reference_steps"] == 60
    assert c["reference_fill"] == pytest.approx(7.81414958 / 8.0, rel=2e-3)
    assert c["reference_wall_median"] > 0 and c["speedup"] > 0
    assert set(c["reference_split"]) >= {"assembly", "linear_solve", "ccd", "contact_build"}


def test_run_measured_reports_exit_code_log_and_peak_memory(tmp_path):
    """The side-by-side scripts' child launch: output into the log, the child's exit code and its own peak RSS."""
    import sys

    code = "import sys; b = bytearray(60 * 2**20); print('child ran'); sys.exit(3)"
    wall, peak_mb, rc = run_measured([sys.executable, "-c", code], dict(os.environ), tmp_path / "log.txt")
    assert rc == 3 and wall > 0
    assert "child ran" in (tmp_path / "log.txt").read_text()
    assert peak_mb >= 60
