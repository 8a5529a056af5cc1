"""Animation repair (paper §7.3) on a generated sequence: two spheres driven through each other and apart.

Properties: every output frame is intersection-free; a frame whose input is clean and reachable comes out equal
to the input bit for bit (so the deviation is exactly zero there); prescribed vertices follow the input exactly;
each input form gives the same repair back in its own form; bad input fails before anything is written; a
repair killed with SIGKILL resumes with its finished frames intact and every later frame repaired and certified."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from idp.applications.repair import repair_scene, run_repair
from idp.contact.intersections import intersecting_pair_keys
from idp.errors import IntersectingInputError, MeshError, SceneError
from idp.mesh.generate import ellipsoid_surface
from idp.mesh.sequence import open_sequence
from idp.output.sequence import sequence_writer

DHAT = 0.01


def two_spheres(num_frames: int = 9, subdivisions: int = 2, depth: float = 0.15, skew: float = 0.0):
    """Frames of two radius-0.3 spheres whose gap goes 0.4 → −``depth`` (crossing) → 0.4 along x; ``skew`` shifts the
    right one along y (mirror-symmetric crossings make edges meet exactly, at zero distance)."""
    s = ellipsoid_surface((0.3, 0.3, 0.3), subdivisions=subdivisions)
    n = s.vertices.shape[0]
    faces = np.vstack([s.faces, s.faces + n])
    gaps = 0.4 - (0.4 + depth) * np.sin(np.pi * np.linspace(0.0, 1.0, num_frames))
    frames = []
    for g in gaps:
        c = 0.3 + g / 2
        frames.append(np.vstack([s.vertices + np.array([-c, 0.0, 0.0]), s.vertices + np.array([c, skew, 0.0])]))
    return np.array(frames), faces, gaps


def _save_npz(path: Path, V: np.ndarray, F: np.ndarray) -> Path:
    np.savez(path, vertices=V, faces=F)
    return path


def _repair(inp: Path, out: Path, **kw):
    return run_repair(repair_scene(inp, dhat=DHAT, **kw), out, progress=False)


@pytest.fixture(scope="module")
def spheres_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("repair")
    V, F, gaps = two_spheres()
    inp = _save_npz(tmp / "spheres.npz", V, F)
    result = _repair(inp, tmp / "out")
    out = open_sequence(tmp / "out" / "spheres.npz")
    return V, F, gaps, result, out


def test_every_output_frame_is_intersection_free(spheres_run):
    V, F, gaps, result, out = spheres_run
    assert out.num_frames == V.shape[0]
    assert (gaps < 0).sum() >= 3  # the input really crosses
    for k in range(out.num_frames):
        assert not intersecting_pair_keys(out.frame(k), F), f"output frame {k} intersects"
    assert result.summary["all_certified"]
    assert result.summary["repair"]["frames_with_output_crossings"] == 0


def test_clean_frames_come_out_unchanged_bit_for_bit(spheres_run):
    V, _F, gaps, result, out = spheres_run
    clean = [k for k in range(V.shape[0]) if gaps[k] > 2 * DHAT]
    assert clean and len(clean) < V.shape[0]
    for k in clean:  # before the approach and after the spheres separate again
        assert np.array_equal(out.frame(k), V[k]), f"clean frame {k} was changed"
    for rec in result.step_records:
        r = rec["repair"]
        if r["frame"] in clean:
            assert r["unchanged"] and r["max_deviation"] == 0.0
    crossing = [k for k in range(V.shape[0]) if gaps[k] < 0]
    assert all(not np.array_equal(out.frame(k), V[k]) for k in crossing)


def test_deviation_is_bounded_by_the_overlap(spheres_run):
    V, _F, gaps, _result, out = spheres_run
    worst = max(np.linalg.norm(out.frame(k) - V[k], axis=1).max() for k in range(V.shape[0]))
    # each sphere gives way by about half the overlap plus the gap d̂; a loose bound that catches runaway motion
    assert worst < 0.5 * float(-gaps.min()) + 4 * DHAT


def test_prescribed_vertices_follow_the_input_exactly(tmp_path):
    V, F, gaps = two_spheres()
    n = V.shape[1] // 2
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    result = _repair(inp, tmp_path / "out", prescribed=[{"indices": list(range(n))}])  # the left sphere
    out = open_sequence(tmp_path / "out" / "spheres.npz")
    for k in range(V.shape[0]):
        assert np.array_equal(out.frame(k)[:n], V[k][:n]), f"prescribed vertices moved off the input in frame {k}"
        assert not intersecting_pair_keys(out.frame(k), F)
    assert all(rec.get("dirichlet", {}).get("met", True) for rec in result.step_records)
    # the right sphere alone gives way: by at least the overlap where the input crosses most
    k = int(np.argmin(gaps))
    assert np.linalg.norm(out.frame(k)[n:] - V[k][n:], axis=1).max() > 0.8 * float(-gaps[k])


def test_pairs_among_held_vertices_leave_the_step_without_changing_it(tmp_path, monkeypatch):
    """The prescribed sphere's vertices are held in every step: its own pairs within d̂ leave the barrier and CCD
    (ContactModel.hold_still), and the repaired frames are those of a run that keeps them. The spheres only touch
    (depth 0: the free one gives way by about d̂ without buckling), so each step has one minimiser and both runs
    take the same Newton path; where a shell buckles (a deep crossing) the barrier's constant offset can change
    which of several minimisers the line search reaches, both certified."""
    from idp.contact.model import ContactModel

    V, F, _gaps = two_spheres(num_frames=5, subdivisions=3, depth=0.0)
    n = V.shape[1] // 2
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    kw = {
        "dhat": 0.05,
        "prescribed": [{"indices": list(range(n))}],
        "newton_tol": 1e-6,
        "prescribed_contact": "guarded",  # else the prescribed group's own pairs are out in both runs
    }
    masked = run_repair(repair_scene(inp, **kw), tmp_path / "masked", progress=False)
    hold_still = ContactModel.hold_still
    monkeypatch.setattr(ContactModel, "hold_still", lambda self, vertices: hold_still(self, None))
    whole = run_repair(repair_scene(inp, **kw), tmp_path / "whole", progress=False)
    a, b = open_sequence(tmp_path / "masked" / "spheres.npz"), open_sequence(tmp_path / "whole" / "spheres.npz")
    moved = 0.0
    for k in range(V.shape[0]):
        assert np.array_equal(a.frame(k)[:n], b.frame(k)[:n])  # on the input in both
        np.testing.assert_allclose(a.frame(k), b.frame(k), rtol=0, atol=1e-9)
        moved = max(moved, float(np.abs(a.frame(k) - V[k]).max()))
    assert moved > 0.02  # the free sphere did give way
    steps = [(r, w) for r, w in zip(masked.step_records, whole.step_records, strict=True) if r.get("newton_iterations")]
    assert steps and all(r["contacts"] < w["contacts"] for r, w in steps)  # the held sphere's own pairs left out
    assert masked.summary["all_certified"] and whole.summary["all_certified"]


@pytest.mark.parametrize("fmt", ["obj", "pvd", "usd"])
def test_each_input_form_repairs_back_into_its_own_form(tmp_path, fmt):
    if fmt == "usd":
        pytest.importorskip("pxr")
    V, F, _ = two_spheres(num_frames=6)
    if fmt == "usd":
        V = V.astype(np.float32).astype(np.float64)  # USD points are float32
    ref_in = _save_npz(tmp_path / "ref.npz", V, F)
    _repair(ref_in, tmp_path / "ref_out")
    ref = open_sequence(tmp_path / "ref_out" / "ref.npz")
    target = {"obj": tmp_path / "in_obj", "pvd": tmp_path / "in_pvd", "usd": tmp_path / "in.usda"}[fmt]
    w = sequence_writer(target, F, format=fmt)
    for k in range(V.shape[0]):
        w.write(k, V[k])
    w.close()
    inp = target / "frames.pvd" if fmt == "pvd" else target
    result = _repair(inp, tmp_path / "out")
    got = open_sequence(result.summary["repaired_sequence"])
    assert got.format == fmt and got.num_frames == V.shape[0]
    tol = 1e-6 if fmt == "usd" else 1e-9  # the same repair from an exact copy of the input (USD: float32 points)
    for k in range(V.shape[0]):
        assert np.allclose(got.frame(k), ref.frame(k), rtol=0, atol=tol)


def test_bad_input_fails_before_anything_is_written(tmp_path):
    V, F, _ = two_spheres(num_frames=5)
    bad = V.copy()
    bad[3, 7, 1] = np.nan
    inp = _save_npz(tmp_path / "nan.npz", bad, F)
    with pytest.raises(MeshError, match=r"frame 3.*vertex 7"):
        _repair(inp, tmp_path / "out_nan")
    assert not (tmp_path / "out_nan").exists()
    with pytest.raises(MeshError, match=r"nothing|no .*obj|empty"):
        (tmp_path / "empty").mkdir()
        _repair(tmp_path / "empty", tmp_path / "out_empty")
    with pytest.raises(MeshError):
        _repair(tmp_path / "nothing_*.obj", tmp_path / "out_glob")
    inp = _save_npz(tmp_path / "ok.npz", V, F)
    with pytest.raises(SceneError, match="selects no vertex"):
        _repair(inp, tmp_path / "out_sel", prescribed=[{"box": [[5, 5, 5], [6, 6, 6]]}])
    assert not (tmp_path / "out_sel").exists()


@pytest.mark.parametrize("skew", [0.0123, 0.0])
def test_a_first_frame_that_crosses_is_refused_or_preserved(tmp_path, skew):
    """Preserved crossings stay and none is added; with skew 0 the mirror-symmetric crossing has edges that meet
    exactly (distance 0), which the barrier cannot hold: they are left out and the run still certifies."""
    V, F, gaps = two_spheres(num_frames=9, skew=skew)
    k = int(np.argmin(gaps))
    inp = _save_npz(tmp_path / "late.npz", V[k:], F)  # starts inside the crossing
    with pytest.raises(IntersectingInputError, match="intersecting"):
        _repair(inp, tmp_path / "out_err")
    result = _repair(inp, tmp_path / "out", first_frame="preserve")
    assert result.summary["all_certified"]
    out = open_sequence(tmp_path / "out" / "late.npz")
    touching = json.loads((tmp_path / "out" / "stats.json").read_text())["meta"]["input_touching_pairs_left_out"]
    assert (touching > 0) == (skew == 0.0)
    first = intersecting_pair_keys(V[k], F)
    for j in range(out.num_frames):  # crossings are kept; only those the touching pairs turn into may appear
        new = intersecting_pair_keys(out.frame(j), F) - first
        assert not new if skew else len(new) <= 4 * len(first), f"frame {j}: {len(new)} new crossing pairs"
    assert result.summary["repair"]["frames_with_output_crossings"] == 0


def test_a_killed_repair_resumes_to_the_same_output(tmp_path):
    V, F, _ = two_spheres(num_frames=24, depth=0.1)
    inp = _save_npz(tmp_path / "long.npz", V, F)
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "idp", "repair", str(inp), "--dhat", str(DHAT), "-q"]
    subprocess.run([*cmd, "-o", str(tmp_path / "whole")], env=env, check=True, capture_output=True)

    killed = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, "-o", str(killed)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checkpoint = killed / "checkpoint.npz"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if int(np.load(checkpoint)["step"]) >= 8:  # past the first contact frames
                break
        except (OSError, ValueError, KeyError, EOFError):
            pass
        time.sleep(0.005)
    if proc.poll() is not None:
        pytest.skip("the repair finished before it could be killed")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = int(np.load(checkpoint)["step"])
    assert not (killed / "long.npz").exists()  # an unfinished repair never looks like a whole sequence
    subprocess.run([*cmd, "-o", str(killed), "--resume"], env=env, check=True, capture_output=True)
    a, b = open_sequence(tmp_path / "whole" / "long.npz"), open_sequence(killed / "long.npz")
    assert a.num_frames == b.num_frames == V.shape[0]
    assert 8 <= killed_at < V.shape[0] - 1
    # the checkpoint holds the whole solver state (κ, the Newton matrix's contact pattern, the conditions'), and
    # both processes run the same operations in the same order: every frame, before and after the kill, is the
    # same bits (without the pattern in the checkpoint they were up to 2e-3 apart after it)
    for k in range(V.shape[0]):
        assert np.array_equal(a.frame(k), b.frame(k)), f"frame {k} differs ({'before' if k <= killed_at else 'after'})"
        assert not intersecting_pair_keys(b.frame(k), F), f"resumed frame {k} intersects"
    assert np.array_equal(a.frame(V.shape[0] - 1), V[-1]) and np.array_equal(b.frame(V.shape[0] - 1), V[-1])


@pytest.mark.parametrize("fmt", ["npz", "obj"])
def test_a_finished_repair_extended_by_resume(tmp_path, fmt):
    """Regression: a repair that finished its --steps and was then resumed with more steps repaired the new
    frames and failed at the end ("cannot finish OUT.npz: frame(s) 0, 1, ... not written"): the assembled npz was
    not taken back. Now the extended output holds every frame, the same as one run of the longer length."""
    V, F, _ = two_spheres()
    inp = _save_npz(tmp_path / "s.npz", V, F)
    scene = repair_scene(inp, dhat=DHAT, output=fmt)
    run_repair(scene, tmp_path / "whole", progress=False, steps=6)
    run_repair(scene, tmp_path / "ext", progress=False, steps=3)
    name = "s.npz" if fmt == "npz" else "frames"
    assert open_sequence(tmp_path / "ext" / name).num_frames == 4
    result = run_repair(scene, tmp_path / "ext", progress=False, steps=6, resume=True)
    a, b = open_sequence(tmp_path / "whole" / name), open_sequence(tmp_path / "ext" / name)
    assert a.num_frames == b.num_frames == 7 and result.summary["all_certified"]
    for k in range(7):
        assert np.array_equal(a.frame(k), b.frame(k)), f"frame {k} differs"
    assert not (tmp_path / "ext" / "s.npz.partial").exists()


def test_cli_arguments_are_checked_with_clear_errors(tmp_path, capsys):
    from idp.applications.repair import parse_frames, parse_selection
    from idp.cli import main

    assert parse_frames("3:10") == (3, 10) and parse_frames(":5") == (0, 5) and parse_frames("2:") == (2, None)
    assert parse_selection("relbox:0,0.8,0,1,1,1") == {"box": [[0, 0.8, 0], [1, 1, 1]], "relative": True}
    assert parse_selection("indices:4, 7 9") == {"indices": [4, 7, 9]}
    V, F, _ = two_spheres(num_frames=4)
    inp = _save_npz(tmp_path / "s.npz", V, F)
    for args, message in [
        (["--frames", "3"], "A:B"),
        (["--frames", "a:b"], "integers"),
        (["--frames", "2:3"], "at least start + 2"),
        (["--fixed", "box:1,2,3"], "6 numbers"),
        (["--fixed", "sphere:1"], "expected box"),
        (["--kappa-b", "-1"], "dirichlet.kappa_initial"),
    ]:
        assert main(["repair", str(inp), "-o", str(tmp_path / "o"), "-q", *args]) == 2
        assert message in capsys.readouterr().err
    assert main(["repair", str(tmp_path / "missing_*.obj"), "-o", str(tmp_path / "o"), "-q"]) == 2
    assert not (tmp_path / "o").exists()


def test_any_scene_object_can_start_from_a_sequence_frame(tmp_path):
    from idp.scene.build import build_scene
    from idp.scene.load import scene_from_dict

    V, F, _ = two_spheres(num_frames=4)
    w = sequence_writer(tmp_path / "frames", F, format="obj")
    for k in range(V.shape[0]):
        w.write(k, V[k])
    w.close()
    for mesh in ("frames", "frames/*.obj"):
        doc = {"objects": [{"name": "s", "kind": "shell", "mesh": mesh, "frame": 3}], "contact": {"dhat": DHAT}}
        built = build_scene(scene_from_dict(doc, base_dir=tmp_path))
        assert np.array_equal(built.system.x, V[3])  # frame 3: apart again (frames 1, 2 cross)


def test_a_guarded_prescribed_group_blocked_by_its_own_crossing_stays_intersection_free_in_every_iterate(tmp_path):
    """Both spheres prescribed and driven through each other (the mannequin's head passing through itself in the
    input), with their pairs guarded (``prescribed_contact = "guarded"``): the straight move onto the input
    collides, the §4.3 penalty pulls with the prescribed DOFs free, and the targets are met once every vertex is
    within the tolerance. Every accepted Newton iterate is certified, the output never crosses, and the vertices
    away from the contact follow the input."""
    V, F, gaps = two_spheres(num_frames=5, subdivisions=2, depth=0.05)
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    scene = repair_scene(
        inp, dhat=0.02, prescribed=[{"indices": list(range(V.shape[1]))}], prescribed_contact="guarded"
    )
    scene.solver.check_every_iterate = True  # a crossing in any accepted iterate fails the run
    result = run_repair(scene, tmp_path / "out", progress=False)
    assert result.summary["all_certified"]
    out = open_sequence(tmp_path / "out" / "spheres.npz")
    k = int(np.argmin(gaps))
    assert gaps[k] < 0  # the input crosses there, so the prescribed spheres cannot both follow it
    assert not intersecting_pair_keys(out.frame(k), F)
    dev = np.linalg.norm(out.frame(k) - V[k], axis=1)
    far = np.abs(V[k][:, 0]) > 0.2  # the spheres' far halves
    assert dev.max() > 0.0 and np.all(dev[far] <= 1e-2 * 0.02 + 1e-15)  # far vertices within the tolerance
    blocked = [r["dirichlet"] for r in result.step_records if r.get("dirichlet") and r["repair"]["frame"] in (k - 1, k)]
    assert blocked and min(d["feasible_fraction"] for d in blocked) < 1.0  # the penalty phase really ran


def test_held_dofs_leave_the_factorisation_without_changing_the_repair(tmp_path, monkeypatch):
    """The prescribed sphere's DOFs are held in every step, so the Newton loop factorises only the free sphere's
    block (idp.solver.held_reduction); the frames equal those of a run that factorises the whole zeroed matrix."""
    import idp.solver.newton as newton

    V, F, _gaps = two_spheres(num_frames=5, subdivisions=3, depth=0.0)
    n = V.shape[1] // 2
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    kw = {"dhat": 0.05, "prescribed": [{"indices": list(range(n))}], "newton_tol": 1e-6}
    sizes: list[int] = []
    factorize = newton.HeldReduction.factorize
    monkeypatch.setattr(
        newton.HeldReduction,
        "factorize",
        lambda self, H, held: (sizes.append(int((~held).sum())), factorize(self, H, held)),
    )
    reduced = run_repair(repair_scene(inp, **kw), tmp_path / "reduced", progress=False)
    assert sizes and max(sizes) <= 3 * n  # only the free sphere's DOFs were factorised
    monkeypatch.setattr(newton, "keeps_vertex_groups", lambda held, d: False)  # the whole matrix, as before
    whole = run_repair(repair_scene(inp, **kw), tmp_path / "whole", progress=False)
    a, b = open_sequence(tmp_path / "reduced" / "spheres.npz"), open_sequence(tmp_path / "whole" / "spheres.npz")
    for k in range(V.shape[0]):
        np.testing.assert_allclose(a.frame(k), b.frame(k), rtol=0, atol=1e-9)
    assert sum(r.get("newton_iterations", 0) for r in reduced.step_records) > 0
    assert reduced.summary["all_certified"] and whole.summary["all_certified"]


def test_a_prescribed_group_follows_its_own_crossing_in_the_input_and_nothing_else_crosses(tmp_path):
    """Both spheres prescribed and driven through each other, with the default ``prescribed_contact =
    "follow_input"`` (the authors' treatment of Dirichlet vertices): pairs among prescribed vertices are out of
    contact, so every frame is the input itself, bit for bit, crossings included; the certificate counts those
    crossings as prescribed and still passes, and the report gives them per frame. A third, free sphere placed where
    the left one passes keeps being pushed away: pairs with a free vertex stay guarded."""
    V, F, gaps = two_spheres(num_frames=5, subdivisions=2, depth=0.05)
    n2 = V.shape[1]
    s = ellipsoid_surface((0.12, 0.12, 0.12), subdivisions=2)
    free = np.array([f[: n2 // 2].mean(axis=0) + np.array([0.0, 0.0, 0.45]) for f in V])  # above the left sphere
    free[2:] = free[1]  # it stays where the left sphere comes to it in frame 2 (z: 0.45 − 0.3 − 0.12 = 0.03 gap)
    free[:, 2] -= np.array([0.0, 0.0, 0.06, 0.06, 0.06])  # and then overlaps it in the input: −0.03
    W = np.concatenate([V, s.vertices[None] + free[:, None, :]], axis=1)
    G = np.vstack([F, s.faces + n2])
    inp = _save_npz(tmp_path / "spheres.npz", W, G)
    result = run_repair(
        repair_scene(inp, dhat=0.02, prescribed=[{"indices": list(range(n2))}]), tmp_path / "out", progress=False
    )
    assert result.summary["all_certified"]
    out = open_sequence(tmp_path / "out" / "spheres.npz")
    k = int(np.argmin(gaps))
    assert gaps[k] < 0
    for j in range(W.shape[0]):
        assert np.array_equal(out.frame(j)[:n2], W[j][:n2])  # the prescribed spheres are the input, bit for bit
    group = np.zeros(W.shape[1], dtype=bool)
    group[:n2] = True
    crossing = intersecting_pair_keys(out.frame(k), G)
    assert crossing  # the prescribed spheres cross each other as in the input ...

    def across(keys):  # crossing pairs with a vertex outside the prescribed group
        return [key for key in keys if not (group[list(key[0])].all() and group[list(key[1])].all())]

    assert any(across(intersecting_pair_keys(W[j], G)) for j in range(W.shape[0]))  # the input's free sphere overlaps
    for j in range(W.shape[0]):
        assert not across(intersecting_pair_keys(out.frame(j), G))  # the output's never does
    rec = next(r for r in result.step_records if r["repair"]["frame"] == k)
    assert rec["repair"]["output_crossing_pairs_prescribed"] == rec["repair"]["output_crossing_pairs_not_preserved"]
    assert rec["certificate"]["prescribed_crossing_pairs"] == len(crossing)
    assert np.abs(out.frame(k)[n2:] - W[k][n2:]).max() > 0.02  # the free sphere gave way


def test_repair_scenes_balance_kappa_once_and_let_prescribed_parts_follow_the_input(tmp_path):
    """A repair's defaults: κ balanced once per run (a frame whose prescribed head starts far from its targets does
    not raise it), pairs among prescribed vertices out of contact; both can be set back."""
    from idp.scene.load import scene_from_dict

    V, F, _ = two_spheres(num_frames=3)
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    scene = repair_scene(inp, prescribed=[{"indices": [0, 1, 2]}])
    assert scene.contact.kappa_init == "once" and scene.repair.prescribed_contact == "follow_input"
    doc = {"repair": {"input": str(inp), "prescribed_contact": "guarded"}, "contact": {"kappa_init": "every_step"}}
    scene = scene_from_dict(doc)
    assert scene.contact.kappa_init == "every_step" and scene.repair.prescribed_contact == "guarded"
    plain = scene_from_dict({"objects": [{"name": "s", "kind": "shell", "mesh": str(inp), "frame": 0}]})
    assert plain.contact.kappa_init == "every_step"
    with pytest.raises(SceneError, match="prescribed_contact"):
        scene_from_dict({"repair": {"input": str(inp), "prescribed_contact": "loose"}})


def test_repair_shells_take_the_gauss_newton_bending_hessian_unless_set(tmp_path):
    """A repair's shell (made by the scene or given) defaults to the Gauss–Newton bending Hessian; a shell that
    sets ``bending_hessian`` keeps it, and a shell outside a repair keeps the projected one."""
    from idp.scene.load import scene_from_dict

    V, F, _ = two_spheres(num_frames=3)
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    assert scene_from_dict({"repair": {"input": str(inp)}}).objects[0].shell.bending_hessian == "gauss_newton"
    given = {"name": "s", "kind": "shell", "mesh": str(inp), "shell": {"youngs_modulus": 50.0}}
    scene = scene_from_dict({"repair": {"input": str(inp)}, "objects": [given]})
    assert scene.objects[0].shell.bending_hessian == "gauss_newton" and scene.objects[0].shell.youngs_modulus == 50
    given["shell"]["bending_hessian"] = "projected"
    scene = scene_from_dict({"repair": {"input": str(inp)}, "objects": [given]})
    assert scene.objects[0].shell.bending_hessian == "projected"
    plain = scene_from_dict({"objects": [{"name": "s", "kind": "shell", "mesh": str(inp), "frame": 0}]})
    assert plain.objects[0].shell is None or plain.objects[0].shell.bending_hessian == "projected"


def test_shell_stencils_on_held_dofs_are_skipped_without_changing_the_repair(tmp_path, monkeypatch):
    """Once the prescribed sphere is held, the membrane and bending stencils whose every DOF is held are not
    evaluated (their gradient and Hessian act on dropped DOFs only); the frames equal those of a run that evaluates
    every stencil."""
    from idp.solver.newton import StepSolver

    V, F, _gaps = two_spheres(num_frames=5, subdivisions=3, depth=0.0)
    n = V.shape[1] // 2
    inp = _save_npz(tmp_path / "spheres.npz", V, F)
    kw = {"dhat": 0.05, "prescribed": [{"indices": list(range(n))}], "newton_tol": 1e-6}
    skipped: list[int] = []
    find = StepSolver._stencils_on_held

    def counting(self, held):
        out = find(self, held)
        skipped.append(sum(int(v.sum()) for v in out.values()))
        return out

    monkeypatch.setattr(StepSolver, "_stencils_on_held", counting)
    lean = run_repair(repair_scene(inp, **kw), tmp_path / "lean", progress=False)
    assert skipped and max(skipped) > 0  # the held sphere's triangles and hinges were skipped
    monkeypatch.setattr(StepSolver, "_stencils_on_held", lambda self, held: {})
    whole = run_repair(repair_scene(inp, **kw), tmp_path / "whole", progress=False)
    a, b = open_sequence(tmp_path / "lean" / "spheres.npz"), open_sequence(tmp_path / "whole" / "spheres.npz")
    for k in range(V.shape[0]):
        np.testing.assert_allclose(a.frame(k), b.frame(k), rtol=0, atol=1e-9)
    assert lean.summary["all_certified"] and whole.summary["all_certified"]
