"""Kernels compiled ahead (idp.kernel_cache): the scene's list matches what a run calls, a cold cache is said out loud
(progress bar, or a line for a kernel compiled on first call) and a warm one prints nothing.

The cold-cache tests run a subprocess with NUMBA_CACHE_DIR set to an empty folder and two or three of the
smallest kernels (a few seconds, most of it numba's start-up); nothing here times anything."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from idp import kernel_cache as kc
from idp.scene.load import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
SMALL = ("_postorder", "_supernodes")  # two of the cheapest kernels (symbolic analysis)


def _python(code: str, cache: Path | None = None, **env: str) -> subprocess.CompletedProcess:
    e = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    if cache is not None:
        e["NUMBA_CACHE_DIR"] = str(cache)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, env=e, timeout=600, check=False
    )


PREPARE = """
    import sys
    from idp import kernel_cache as kc
    kernels = [k for k in kc.KERNELS if k.name in {names!r}]
    with kc.announcing({announce}):
        done = kc.prepare(kernels, helper={helper})
    print(sorted(k.name for k in done))
    print([kc.is_cached(k) for k in kernels])
"""


@pytest.mark.parametrize("helper", [False, True])
def test_cold_cache_shows_a_progress_bar_and_warm_cache_prints_nothing(tmp_path, helper):
    code = PREPARE.format(names=SMALL, announce=True, helper=helper)
    cold = _python(code, tmp_path)
    assert cold.returncode == 0, cold.stderr
    assert cold.stdout.splitlines() == [str(sorted(SMALL)), "[True, True]"]
    assert "compiling kernels (first run only)" in cold.stderr
    assert "2/2" in cold.stderr
    assert any(p.suffix == ".nbc" for p in tmp_path.rglob("*")), "numba wrote no cache"
    warm = _python(code, tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert warm.stdout.splitlines() == ["[]", "[True, True]"]
    assert warm.stderr == ""


def test_not_announcing_compiles_silently(tmp_path):
    r = _python(PREPARE.format(names=SMALL, announce=False, helper=True), tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0] == str(sorted(SMALL))
    assert r.stderr == ""


def test_helper_process_compiles_what_it_claims_into_the_shared_cache(tmp_path):
    import idp

    i, j = (kc.KERNELS.index(k) for k in kc.KERNELS if k.name in SMALL)
    claims = tmp_path / "claims"
    claims.mkdir()
    (claims / str(j)).touch()  # j is taken by "another process": the helper leaves it
    cache = tmp_path / "cache"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(cache)}
    package = str(Path(idp.__file__).resolve().parent)
    cmd = [sys.executable, "-m", "idp._compile_helper", package, str(claims), str(i), str(j)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["start", str(i), "done", str(i)]
    check = _python(
        f"from idp import kernel_cache as kc; print(kc.is_cached(kc.KERNELS[{i}]), kc.is_cached(kc.KERNELS[{j}]))",
        cache,
    )
    assert check.stdout.split() == ["True", "False"]
    # another idp than the parent's: it compiles nothing (its cache would not be the parent's)
    r = subprocess.run([*cmd[:3], str(tmp_path), *cmd[4:]], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 2 and r.stdout == ""


def test_a_failed_helper_leaves_the_work_to_this_process(tmp_path):
    code = f"""
        import sys
        from idp import kernel_cache as kc
        kc._start_helper = lambda claims, indices, err: __import__("subprocess").Popen(
            [sys.executable, "-c", "import sys; sys.exit(3)"], stdout=__import__("subprocess").PIPE, text=True
        )
        kernels = [k for k in kc.KERNELS if k.name in {SMALL!r}]
        with kc.announcing():
            kc.prepare(kernels, helper=True)
        print([kc.is_cached(k) for k in kernels])
    """
    r = _python(code, tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[True, True]"
    assert "2/2" in r.stderr


def test_a_kernel_compiled_on_first_call_is_announced_once(tmp_path):
    code = """
        import numpy as np
        from idp import kernel_cache as kc
        from idp.solver.symbolic import _postorder
        with kc.announcing():
            _postorder(np.array([1, 2, -1], dtype=np.int64), 3)
            _postorder(np.array([1, 2, -1], dtype=np.int64), 3)
    """
    cold = _python(code, tmp_path)
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count("compiling kernel symbolic._postorder (first run only") == 1
    warm = _python(code, tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert warm.stderr == ""


def test_announcing_is_off_outside_the_context_and_nests():
    assert kc._announce_depth == 0
    with kc.announcing():
        with kc.announcing():
            assert kc._announce_depth == 2
        with kc.announcing(False):
            assert kc._announce_depth == 1
    assert kc._announce_depth == 0 and kc._listener is None


@pytest.mark.parametrize(("argv", "shown"), [(["demo"], True), (["demo", "-q"], False)])
def test_cli_announces_unless_quiet(tmp_path, monkeypatch, argv, shown):
    import idp.scene.build as build
    from idp.cli import main

    seen = []

    def fake_prepare(scene):
        seen.append(kc._announce_depth > 0)
        raise KeyboardInterrupt  # stop before anything runs

    monkeypatch.setattr(build, "prepare_kernels", fake_prepare)
    assert main([*argv, "-o", str(tmp_path / "out")]) == 130
    assert seen == [shown]


# --------------------------------------------------------------------------------------------------
# the lists against what runs call
# --------------------------------------------------------------------------------------------------

ENTRIES = """
    import gc, json, sys
    from numba.core.registry import CPUDispatcher
    from idp.api import simulate
    from idp.scene.load import load_scene
    scene = load_scene(sys.argv[1])
    simulate(scene, sys.argv[2], progress=False)
    used = sorted(
        [o.py_func.__module__, o.py_func.__name__, [str(t) for t in sig]]
        for o in gc.get_objects()
        if isinstance(o, CPUDispatcher) and o.py_func.__module__.startswith("idp.")
        for sig in o.signatures
    )
    print(json.dumps(used))
"""

SCENES = {
    # contacts from step 8 on
    "demo": lambda: _demo(steps=9),
    "disk_2d": lambda: json.loads((Path(__file__).parent / "scenes" / "disk_in_ring_2d.json").read_text()),
    "ball_in_shell": lambda: {
        "name": "shell3d",
        "time": {"h": 0.0016, "steps": 4},
        "objects": [
            {
                "name": "ball",
                "generate": {"shape": "ball", "radius": 0.25, "resolution": 3},
                "rest_shape": {"growth_rate": 0.2, "growth_steps": 6},
            },
            {
                "name": "s",
                "kind": "shell",
                "generate": {"shape": "ellipsoid_surface", "radii": [0.3, 0.3, 0.3], "subdivisions": 2},
            },
        ],
    },
}


def _demo(steps: int) -> dict:
    from idp.cli import demo_scene_path
    from idp.scene.load import resolved_scene_dict

    d = resolved_scene_dict(load_scene(demo_scene_path()))
    d["time"]["steps"] = steps
    return d


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_kernels_are_the_kernels_the_run_calls(tmp_path, name):
    """With a warm cache only the kernels called from Python are loaded (their callees come compiled inside them),
    so the dispatchers holding signatures after a run are exactly its entry kernels: the list must name each
    with the argument types the run passed (else the run compiles a kernel of its own on a cold cache)."""
    doc = SCENES[name]()
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps(doc))
    runs = []
    for out in ("a", "b"):  # the first warms the cache (nothing to do when it is warm), the second is measured
        r = subprocess.run(
            [sys.executable, "-c", textwrap.dedent(ENTRIES), str(scene_file), str(tmp_path / out)],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            timeout=900,
            check=False,
        )
        assert r.returncode == 0, r.stderr
        runs.append(r)
    used = {(m, n, ", ".join(sig)) for m, n, sig in json.loads(runs[1].stdout.splitlines()[-1])}
    kernels = kc.scene_kernels(scene_from_dict(doc))
    planned = {(k.module, k.name, ", ".join(map(str, kc._argtypes(k)))) for k in kernels}
    alternatives = {(k.module, k.name, ", ".join(map(str, kc._argtypes(k)))) for k in kernels if k.alternative}
    assert used <= planned  # nothing compiled outside the plan
    assert planned - used <= alternatives  # and nothing planned that the run does not call (but for either-or pairs)
