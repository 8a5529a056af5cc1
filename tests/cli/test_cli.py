"""The CLI on a tiny scene writes readable OBJ/VTU/PVD/stats/PNG; bad input gives a clear message and exit code."""

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import matplotlib.image as mpimg
import meshio

from idp.cli import main
from idp.mesh.generate import tet_ball
from idp.mesh.io import write_mesh

TINY = """
name = "tiny"
[time]
h = 0.0016
steps = 3
[solver]
newton_tol = 0.1
[contact]
dhat = 2e-3
dhat_mode = "relative"
[[objects]]
name = "ball"
mesh = "ball.vtk"
rest_shape = {{ growth_rate = 0.2, growth_steps = 3 }}
[[objects]]
name = "box"
kind = "obstacle"
generate = {{ shape = "box_surface", lo = [-0.45, -0.45, -0.45], hi = [0.45, 0.45, 0.45], resolution = 2 }}
{extra}
"""


def write_scene(tmp_path: Path, extra: str = "") -> Path:
    write_mesh(tmp_path / "ball.vtk", tet_ball(0.3, resolution=2))
    p = tmp_path / "tiny.toml"
    p.write_text(TINY.format(extra=extra))
    return p


def test_run_writes_every_output(tmp_path, capsys):
    scene = write_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(scene), "-o", str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "fill fraction" in printed and "all frames certified" in printed
    objs = sorted((out / "obj").glob("frame_*.obj"))
    vtus = sorted((out / "vtu").glob("frame_*.vtu"))
    assert len(objs) == 4 and len(vtus) == 4
    text = objs[-1].read_text()
    assert "o ball" in text and "o box" in text and text.count("\nf ") > 100
    m = meshio.read(vtus[-1])
    assert "tetra" in m.cells_dict and "triangle" in m.cells_dict
    pvd = ET.parse(out / "frames.pvd").getroot()
    assert len(pvd.findall(".//DataSet")) == 4
    stats = json.loads((out / "stats.json").read_text())
    assert stats["summary"]["all_certified"] is True and len(stats["steps"]) == 4
    step = stats["steps"][-1]
    for key in (
        "wall_time",
        "newton_iterations",
        "alphas",
        "ccd_alphas",
        "contacts",
        "kappa",
        "energy",
        "min_distance",
        "certificate",
        "timings",
    ):
        assert key in step
    assert stats["meta"]["dhat"] > 0  # the resolved absolute d̂ is saved
    img = mpimg.imread(out / "frames.png")
    assert img.shape[0] > 100 and img.std() > 0.01
    resolved = json.loads((out / "scene.resolved.json").read_text())
    assert resolved["solver"]["max_newton_iterations"] >= 1  # defaults written out


def test_bad_scene_key_names_the_path(tmp_path, capsys):
    scene = write_scene(tmp_path, extra="[solverr]\nnewton_tol = 1.0\n")
    assert main(["run", str(scene), "-o", str(tmp_path / "o"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "solverr" in err and "Traceback" not in err


def test_missing_mesh_is_named(tmp_path, capsys):
    scene = write_scene(tmp_path)
    (tmp_path / "ball.vtk").unlink()
    assert main(["run", str(scene), "-q"]) == 2
    assert "ball.vtk" in capsys.readouterr().err


def test_check_reports_meshes(tmp_path, capsys):
    write_mesh(tmp_path / "ball.vtk", tet_ball(0.3, resolution=2))
    assert main(["check", str(tmp_path / "ball.vtk")]) == 0
    out = capsys.readouterr().out
    assert "ball.vtk" in out
    assert main(["check", str(tmp_path / "nope.vtk")]) == 1


def test_module_entry_point_runs():
    r = subprocess.run([sys.executable, "-m", "idp", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "run" in r.stdout and "check" in r.stdout


def test_threads_option_reaches_numba_blas_and_cholmod(tmp_path):
    """``--threads 1`` reaches numba, every BLAS pool and CHOLMOD's routed BLAS even when numba and scipy's OpenBLAS
    were loaded before the option was read (a script that imports them first, then calls the CLI's ``main``)."""
    scene = write_scene(tmp_path)
    probe = (
        "import sys\n"
        "import numba, numpy, scipy.linalg\n"
        "from idp.cli import main\n"
        "assert main(['run', sys.argv[1], '-o', sys.argv[2], '-q', '--threads', '1']) == 0\n"
        "import numba\n"
        "from threadpoolctl import threadpool_info\n"
        "import idp.solver.cholmod_blas as cb\n"
        "pools = sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})\n"
        "print('RESULT', numba.get_num_threads(), cb._threads, pools)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", probe, str(scene), str(tmp_path / "out")], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr[-2000:]
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT")][-1]
    assert line == "RESULT 1 1 [1]", line
