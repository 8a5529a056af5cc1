"""Fuzzing the command line: ``idp.cli.main(argv)`` in-process with random argument lists for ``run``, ``flow``,
``font``, ``repair``, ``uv`` and ``check``, built from the parser's real options (``build_parser()``), and a few
runs of ``python -m idp`` as a subprocess.

Property: ``main`` returns (or argparse exits with) 2 and prints ``idp: error: ...`` (argparse: ``usage: ...``) for
bad input, or finishes a clean run (0; 3 or 4 with their one-line ``idp: certificate failure`` / ``idp: solver
error`` message); ``idp check`` reports an unreadable mesh as a failed check (exit 1, by design). Never an uncaught
exception, never a traceback. Inputs are tiny (a tetrahedron, a two-frame npz, a 3x1 cut cylinder, a scene of one
6-tet box read from a file) and ``--steps`` is at most 1, so a run that starts ends in a second or two.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pytest
from fuzz.common import fuzz, mutated_bytes
from hypothesis import event, given
from hypothesis import strategies as st
from threadpoolctl import ThreadpoolController

from idp.cli import build_parser, main
from idp.mesh.generate import tet_box
from idp.mesh.io import write_mesh
from idp.mesh.uv_obj import cut_cylinder_obj_text

TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
SCENE = {
    "time": {"steps": 1},
    "solver": {"newton_tol": 0.5},
    "output": {"png": False, "vtu": False},
    # a mesh file, not a generator: no mutated number can turn the scene into a long run of a huge mesh
    "objects": [{"name": "box", "mesh": "box.vtk"}],
}
VERBS = ("run", "flow", "font", "repair", "uv", "check")
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def _inputs(d: Path) -> dict[str, Path]:
    """The tiny valid inputs each verb reads, plus a file where a folder is expected and a binary file."""
    (d / "tetra.obj").write_text(TETRA_OBJ)
    (d / "uv.obj").write_text(cut_cylinder_obj_text(3, 1))
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    np.savez(
        d / "seq.npz", vertices=np.stack([x, 1.01 * x]), faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    )
    write_mesh(d / "box.vtk", tet_box((0, 0, 0), (1, 1, 1), 1))
    (d / "scene.json").write_text(json.dumps(SCENE))
    (d / "indices.txt").write_text("0 1\n")
    (d / "binary.bin").write_bytes(bytes(range(256)))
    (d / "afile").write_text("not a folder")
    return {
        "run": d / "scene.json",
        "flow": d / "tetra.obj",
        "repair": d / "seq.npz",
        "uv": d / "uv.obj",
        "check": d / "tetra.obj",
        "binary": d / "binary.bin",
        "afile": d / "afile",
        "indices": d / "indices.txt",
    }


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


SUBPARSERS = _subparsers()
ODD = st.sampled_from(["", "-", "--", "nan", "inf", "-inf", "1e999", "-1", "0", "x", "\x00", "é", "-o", "--steps"])


CLEAN = {
    "steps": "1",
    "threads": "1",
    "fixed": "relbox:0,0,0,0.5,0.5,0.5",
    "frames": "0:2",
    "edge_length": "0.03",
    "height": "0.3",
    "p": "2",
}


def _value(draw: st.DrawFn, action: argparse.Action, files: dict[str, Path], out: Path, clean: bool) -> list[str]:
    """A random value for one option, in the option's own terms most of the time; a valid one when ``clean``."""
    dest = action.dest
    if clean:
        if action.choices is not None:
            return [draw(st.sampled_from(list(action.choices)))]
        if dest in ("output", "report"):
            return [str(out / dest)]
        return [CLEAN.get(dest, "0.01")]
    if draw(st.integers(0, 5)) == 0:
        return [draw(ODD)]
    if dest == "steps":
        return [draw(st.sampled_from(["1", "1", "0", "-1", "-7", "x", "1.5", ""]))]
    if dest == "threads":
        return [draw(st.sampled_from(["1", "2", "0", "-1", "-4", "100000", "x"]))]
    if dest == "output":
        return [str(draw(st.sampled_from([out, out / "sub" / "dir", files["afile"], files["afile"] / "below"])))]
    if dest in ("font", "report", "usd_prim"):
        return [draw(st.sampled_from([str(files["binary"]), str(out / "nope"), "/", str(files["afile"])]))]
    if dest == "fixed":
        kind = draw(st.sampled_from(["box", "relbox", "indices", "junk"]))
        if kind == "indices":
            body = draw(
                st.sampled_from(
                    ["0,1", "-1", "99999999999999999999999", "a,b", "", str(files["binary"]), str(files["indices"])]
                )
            )
        else:
            body = ",".join(draw(st.lists(st.sampled_from(["0", "1", "0.5", "-1", "nan", "inf", "x"]), max_size=7)))
        return [f"{kind}:{body}"]
    if dest == "frames":
        return [draw(st.sampled_from(["0:2", ":", "1:", "0:1", "5:1", "a:b", "0", "0:99999999999999999999999"]))]
    if dest == "edge_length":
        return [draw(st.sampled_from(["0.05", "1e-300", "0", "-1", "1e300", "nan"]))]
    if dest == "height":
        return [draw(st.sampled_from(["0.3", "1e300", "1e-300", "0", "-1", "inf"]))]
    if action.choices is not None:
        return [draw(st.one_of(st.sampled_from(list(action.choices)), ODD))]
    if action.type is float:
        return [draw(st.sampled_from(["0.01", "1", "0", "-1", "1e-12", "1e12", "nan", "inf", "-inf", "x"]))]
    if action.type is int:
        return [draw(st.sampled_from(["1", "0", "-1", "2", "x"]))]
    return [draw(st.text(max_size=8))]


@st.composite
def argv_for(draw: st.DrawFn, verb: str, files: dict[str, Path], out: Path) -> list[str]:
    parser = SUBPARSERS[verb]
    argv: list[str] = [verb]
    positional: list[str] = []
    clean = draw(st.integers(0, 2)) == 0  # every option valid: a run that starts (and must end cleanly)
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if not action.option_strings:  # positional
            if verb == "font":
                texts = ["A", "Hi"] if clean else ["A", "Hi", "", " ", "\n", "\x00", "é€", "A" * 3]
                positional.append(draw(st.sampled_from(texts)))
            elif verb == "check":
                pool = [
                    files["check"],
                    files["binary"],
                    files["afile"],
                    out / "missing.vtk",
                    Path("/"),
                    Path("x" * 5000),
                ]
                positional += [str(p) for p in draw(st.lists(st.sampled_from(pool), min_size=0, max_size=3))]
            else:
                pool = [files[verb], files[verb], files["binary"], files["afile"], out / "missing" / "x.obj"]
                positional.append(str(files[verb] if clean else draw(st.sampled_from(pool))))
            continue
        required = getattr(action, "required", False)
        if not required and (draw(st.integers(0, 2)) != 0 or (clean and action.dest in ("font", "usd_prim", "resume"))):
            continue
        flag = draw(st.sampled_from(action.option_strings))
        if action.nargs == 0:
            argv.append(flag)
        else:
            argv += [flag, *_value(draw, action, files, out, clean)]
    if verb != "check" and "--steps" not in argv and any(a.dest == "steps" for a in parser._actions):
        argv += ["--steps", "1"]  # a run that starts stays tiny
    if verb == "font" and "--edge-length" not in argv:
        argv += ["--edge-length", "0.03"]  # ~100 triangles a glyph at the default height, not ~1000
    if verb in ("run", "flow", "font", "repair", "uv") and "-q" not in argv and "--quiet" not in argv:
        argv.append("-q")
    if draw(st.booleans()):
        argv = [*argv[:1], *positional, *argv[1:]]
    else:
        argv += positional
    return argv


CALL_BUDGET = 2 * 2**30  # address space one in-process call may add (runs here are tiny: ~300 MB at most)


@contextlib.contextmanager
def _memory_cap() -> Iterator[None]:
    """Cap this process's address space at its size now + CALL_BUDGET while ``main`` runs, so an input that makes
    a run grow without bound fails fast with a MemoryError (which the CLI reports) instead of taking the machine."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with open("/proc/self/status") as fh:
        vm = int(fh.read().split("VmSize:")[1].split()[0]) * 1024
    cap = vm + CALL_BUDGET if hard == resource.RLIM_INFINITY else min(vm + CALL_BUDGET, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def call(argv: list[str], workdir: Path | None = None) -> tuple[int, str, str]:
    """``main(argv)`` with stdout/stderr captured and the thread settings it may change restored; SystemExit
    (argparse) is turned into its code. Any other exception propagates and fails the test."""
    saved = {k: os.environ.get(k) for k in THREAD_VARS}
    numba_threads = numba.get_num_threads()  # --threads sets numba's count and the loaded BLAS pools directly
    pools = [(lib, lib.num_threads) for lib in ThreadpoolController().lib_controllers]
    out, err = io.StringIO(), io.StringIO()
    cwd = os.getcwd()
    try:
        if workdir is not None:
            os.chdir(workdir)  # relative paths (an output named "nan" or "-") land in the test's folder
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), _memory_cap():
            try:
                code: Any = main(argv)
            except SystemExit as exc:
                code = exc.code
    finally:
        os.chdir(cwd)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if "--threads" in argv:
            import ipctk

            ipctk.set_num_threads(1)
            numba.set_num_threads(numba_threads)
            for lib, n in pools:
                lib.set_num_threads(n)
    return int(code or 0), out.getvalue(), err.getvalue()


def check_outcome(argv: list[str], code: int, err: str) -> None:
    assert "Traceback" not in err, err
    if argv[0] == "check":
        assert code in (0, 1, 2), (code, err)
    else:
        assert code in (0, 2, 3, 4), (argv, code, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if code == 2:
        assert lines, f"exit 2 without a message: {argv}"
        first = lines[0]
        usage = first.startswith("usage: ") and lines[-1].startswith("idp")
        assert usage or first.startswith("idp: error: "), (argv, err[-2000:])
    elif code == 3:
        assert any(ln.startswith("idp: certificate failure") or "FAILED" in ln for ln in lines) or code == 3
    elif code == 4:
        assert any(ln.startswith("idp: solver error: ") for ln in lines), (argv, err[-2000:])


def _random_arguments_test(verb: str, examples: int) -> Any:
    @fuzz(examples)
    @given(data=st.data())
    def test(data: st.DataObject) -> None:
        with tempfile.TemporaryDirectory() as d:
            files = _inputs(Path(d))
            argv = data.draw(argv_for(verb, files, Path(d) / "out"), label="argv")
            code, _out, err = call(argv, Path(d))
            event(f"exit {code}")
            check_outcome(argv, code, err)

    test.__name__ = f"test_cli_random_arguments_{verb}"
    test.__doc__ = f"Random argument lists for idp {verb}: exit 2 with a message, or a clean run."
    return test


test_cli_random_arguments_run = _random_arguments_test("run", 15)
test_cli_random_arguments_flow = _random_arguments_test("flow", 15)
test_cli_random_arguments_font = _random_arguments_test("font", 12)
test_cli_random_arguments_repair = _random_arguments_test("repair", 15)
test_cli_random_arguments_uv = _random_arguments_test("uv", 15)
test_cli_random_arguments_check = _random_arguments_test("check", 40)


@fuzz(30)
@given(data=st.data())
def test_cli_mutated_inputs(data):
    """The verbs' own input files, mutated (the readers' fuzzing, seen through the CLI)."""
    verb = data.draw(st.sampled_from(["run", "flow", "repair", "uv", "check"]), label="verb")
    with tempfile.TemporaryDirectory() as d:
        files = _inputs(Path(d))
        path = files[verb]
        path.write_bytes(data.draw(mutated_bytes(path.read_bytes()), label="file"))
        argv = [verb, str(path)]
        if verb != "check":
            argv += ["-o", str(Path(d) / "out.obj" if verb == "uv" else Path(d) / "out"), "--steps", "1", "-q"]
        code, _out, err = call(argv, Path(d))
        event(f"exit {code}")
        check_outcome(argv, code, err)


def _module(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "idp", *args], capture_output=True, text=True, timeout=300, cwd=cwd, env=env
    )


@pytest.mark.parametrize(
    "args",
    [
        ["check", "binary.bin", "tetra.obj"],
        ["flow", "binary.bin", "--steps", "1"],
        ["run", "scene.json", "--threads", "-3", "-o", "out"],
        ["repair", "seq.npz", "--fixed", "indices:binary.bin"],
        ["uv", "tetra.obj", "-o", "afile"],
        ["nope"],
    ],
    ids=lambda a: " ".join(a)[:40],
)
def test_python_m_idp(tmp_path, args):
    """A few runs as a real process: exit 2 (0/1 for check) and a one-line ``idp: error:`` (or usage) on stderr."""
    _inputs(tmp_path)
    proc = _module(*args, cwd=tmp_path)
    assert "Traceback" not in proc.stderr, proc.stderr
    if args[0] == "check":
        assert proc.returncode == 1 and "cannot read mesh file" in proc.stdout
        return
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("idp: error: ") or (last.startswith("idp") and ": error: " in last), proc.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "{scene}", "-o", "{afile}", "-q"],
        ["run", "{scene}", "-o", "{afile}/below", "-q"],
        ["flow", "{tetra}", "--steps", "1", "-o", "{afile}", "-q"],
        ["font", "A", "--steps", "1", "-o", "{afile}", "-q"],
        ["repair", "{seq}", "-o", "{afile}", "-q"],
        ["uv", "{uv}", "-o", "{afile}/x.obj", "-q"],
        ["uv", "{uv}", "-o", "{dir}", "-q"],
        ["uv", "{uv}", "-o", "{dir}/x.obj", "--report", "{afile}", "-q"],
    ],
    ids=lambda a: " ".join(a)[:40],
)
def test_output_where_a_file_is(tmp_path, argv):
    """Regression: an output folder that is an existing file raised FileExistsError / NotADirectoryError (after
    the scene was built); now exit 2 naming the path, and nothing is written."""
    files = _inputs(tmp_path)
    names = {"scene": files["run"], "afile": files["afile"], "tetra": files["flow"], "seq": files["repair"]}
    names |= {"uv": files["uv"], "dir": tmp_path}
    argv = [a.format(**{k: str(v) for k, v in names.items()}) for a in argv]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code, _out, err = call(argv, tmp_path)
    assert code == 2 and err.startswith("idp: error: ") and ("afile" in err or "folder" in err), (code, err)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


@pytest.mark.parametrize("value", ["-3", "0", "100000"])
def test_threads_out_of_range(tmp_path, value):
    """Regression: --threads -3 wrote NUMBA_NUM_THREADS=-3 into the environment (numba then refused to start) and
    --threads 100000 crashed the process (SIGSEGV); both are usage errors now."""
    files = _inputs(tmp_path)
    code, _out, err = call(["run", str(files["run"]), "--threads", value, "-o", str(tmp_path / "o"), "-q"], tmp_path)
    assert code == 2 and "argument --threads: must be between 1 and" in err, err
    assert not (tmp_path / "o").exists()


def test_font_path_with_a_nul_byte(tmp_path):
    """Regression (hypothesis): --font with an embedded NUL byte raised ValueError from pathlib; a clear error now."""
    code, _out, err = call(["font", "A", "--font", "a\x00b", "--steps", "1", "-o", str(tmp_path / "o"), "-q"], tmp_path)
    assert code == 2 and "cannot read font file 'a\\x00b'" in err, (code, err)


def test_fixed_index_file_not_text(tmp_path):
    """Regression: repair --fixed indices:FILE with a binary FILE raised UnicodeDecodeError."""
    files = _inputs(tmp_path)
    argv = ["repair", str(files["repair"]), "--fixed", f"indices:{files['binary']}", "-o", str(tmp_path / "o"), "-q"]
    code, _out, err = call(argv, tmp_path)
    assert code == 2 and err.startswith("idp: error: --fixed") and "cannot read the index file" in err, err


def test_fixed_index_beyond_int64(tmp_path):
    """Regression: repair --fixed indices:99999999999999999999999 reached numpy as an OverflowError."""
    files = _inputs(tmp_path)
    argv = ["repair", str(files["repair"]), "--fixed", "indices:99999999999999999999999", "-o", str(tmp_path / "o")]
    code, _out, err = call([*argv, "-q"], tmp_path)
    assert code == 2 and "repair.prescribed[0].indices[0]: must be <= 9223372036854775807" in err, err


@pytest.mark.parametrize(
    "args",
    [["--height", "1e300"], ["--height", "1e-300"], ["--edge-length", "1e-300"], ["--edge-length", "1e300"]],
    ids=lambda a: " ".join(a),
)
def test_font_scale_limits(tmp_path, args):
    """Regression: --height 1e300 and --edge-length 1e-300 raised GEOSException, --edge-length 1e300 OverflowError;
    edge lengths far below height/400 took minutes to mesh. All are refused before meshing now."""
    code, _out, err = call(["font", "A", *args, "--steps", "1", "-o", str(tmp_path / "o"), "-q"], tmp_path)
    assert code == 2 and err.startswith("idp: error: ") and ("height must be" in err or "edge_length must" in err)
    assert not (tmp_path / "o").exists()


def test_stdout_closed_early(tmp_path):
    """Regression: 'idp check ... | head' (stdout's reader gone) ended in a BrokenPipeError traceback."""
    _inputs(tmp_path)
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "idp", "check", *["tetra.obj"] * 50],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away before idp writes
    with proc.stderr:
        err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141 and "Traceback" not in err, err


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """The output folder of a one-step run of the tiny scene (its checkpoint.npz is what --resume reads)."""
    d = tmp_path_factory.mktemp("resume")
    files = _inputs(d)
    code, _out, err = call(["run", str(files["run"]), "-o", str(d / "out"), "-q"], d)
    assert code == 0, err
    return d


@st.composite
def checkpoints(draw: st.DrawFn, valid: bytes) -> bytes:
    """The run's checkpoint, byte-mutated, or rewritten with a key dropped or of the wrong shape / dtype."""
    if draw(st.booleans()):
        return draw(mutated_bytes(valid, max_ops=2))
    with np.load(io.BytesIO(valid)) as data:
        arrays = {k: data[k] for k in data.files}
    key = draw(st.sampled_from(sorted(arrays)))
    what = draw(st.sampled_from(["drop", "shape", "dtype", "nan", "huge"]))
    if what == "drop":
        del arrays[key]
    elif what == "shape":
        arrays[key] = np.zeros(draw(st.sampled_from([(), (0,), (3,), (2, 2), (5, 3, 1)])))
    elif what == "dtype":
        with np.errstate(over="ignore", invalid="ignore"):
            arrays[key] = arrays[key].astype(draw(st.sampled_from(["U4", "c16", "bool", "int8", "f2"])))
    elif what == "nan":
        arrays[key] = np.full(arrays[key].shape, np.nan)
    else:
        arrays[key] = np.full(arrays[key].shape, 2**62, dtype=np.int64)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@fuzz(25)
@given(data=st.data())
def test_resume_from_a_damaged_checkpoint(finished_run, data):
    """--resume reads OUT/checkpoint.npz: a damaged one is refused with a message (exit 4, as for a checkpoint of
    another scene) or resumed cleanly, never a traceback."""
    valid = (finished_run / "out" / "checkpoint.npz").read_bytes()
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "out"
        out.mkdir()
        (out / "checkpoint.npz").write_bytes(data.draw(checkpoints(valid), label="checkpoint"))
        argv = ["run", str(finished_run / "scene.json"), "-o", str(out), "--resume", "--steps", "2", "-q"]
        code, _out, err = call(argv, Path(d))
        event(f"exit {code}")
        check_outcome(argv, code, err)


@pytest.mark.parametrize("damage", [b"", b"garbage\x00\xff", b"PK\x03\x04"])
def test_unreadable_checkpoint(finished_run, tmp_path, damage):
    """Regression: --resume with an empty or non-npz checkpoint raised EOFError / ValueError from np.load."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "checkpoint.npz").write_bytes(damage)
    argv = ["run", str(finished_run / "scene.json"), "-o", str(out), "--resume", "-q"]
    code, _out, err = call(argv, tmp_path)
    assert code == 4 and err.startswith("idp: solver error: checkpoint") and "unreadable" in err, err


@pytest.mark.parametrize("flag", [np.zeros(0, dtype=bool), np.array([1.5]), np.array("yes")])
def test_checkpoint_with_a_damaged_kappa_flag(finished_run, tmp_path, flag):
    """Regression (hypothesis): a checkpoint whose optional kappa_initialized is not a scalar flag raised
    'truth value of an empty array is ambiguous' on --resume; it is refused with a message naming the key."""
    with np.load(finished_run / "out" / "checkpoint.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["kappa_initialized"] = flag
    out = tmp_path / "out"
    out.mkdir()
    np.savez(out / "checkpoint.npz", **arrays)
    argv = ["run", str(finished_run / "scene.json"), "-o", str(out), "--resume", "-q"]
    code, _out, err = call(argv, tmp_path)
    assert code == 4 and "kappa_initialized not as idp writes them" in err, err


def test_scene_output_dir_only_without_o(tmp_path):
    """A scene's output.dir (resolved against the scene's folder, wherever it points) is used only when 'idp run'
    is given no -o; with -o nothing is written there. Loading alone never creates it."""
    files = _inputs(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    scene = json.loads(files["run"].read_text())
    scene["output"]["dir"] = "elsewhere"
    files["run"].write_text(json.dumps(scene))
    code, _out, err = call(["run", str(files["run"]), "-o", str(tmp_path / "given"), "-q"], tmp_path)
    assert code == 0, err
    assert (tmp_path / "given" / "stats.json").is_file() and not elsewhere.exists()
    code, _out, err = call(["run", str(files["run"]), "-q"], tmp_path / "given")  # another working folder
    assert code == 0, err
    assert (elsewhere / "stats.json").is_file()


def test_out_of_memory_is_a_message(tmp_path, monkeypatch):
    """Regression: a UV layout with one vertex at 3.4e11 (a mutated input) made Newton's steps so long that ipctk's
    CCD raised MemoryError (std::bad_alloc after allocating 13 GB), a traceback from main. Now the solver's exit
    code and a one-line message; the run itself is slow (minutes), so the regression raises the error directly."""
    import idp.applications.uv_map as uv_map

    def exhausted(*_args: Any, **_kwargs: Any) -> Any:
        raise MemoryError("std::bad_alloc")

    monkeypatch.setattr(uv_map, "run_uv", exhausted)
    files = _inputs(tmp_path)
    code, _out, err = call(["uv", str(files["uv"]), "-o", str(tmp_path / "o.obj"), "-q"], tmp_path)
    assert code == 4 and err == "idp: solver error: out of memory (std::bad_alloc)\n", err
