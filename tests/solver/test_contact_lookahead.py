"""Contact look-ahead (``[solver] contact_lookahead``): the search matrix of a Newton iteration also sees pairs
just outside d̂ once CCD has cut a step short. Only the search direction changes: every iterate must still be
intersection- and inversion-free (independent certificate on each), and each step may stop only on an exact
matrix's decrement."""

from __future__ import annotations

import numpy as np
import pytest
from contact.test_compiled_barrier import stacked

from idp.api import simulate
from idp.bench.suite import _ball_in_box
from idp.contact import compiled_barrier as cb
from idp.contact.model import ContactModel
from idp.errors import SceneError
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict
from idp.solver.newton import contact_lookahead_reach


def _pressed_ball(lookahead: float) -> dict:
    """The bench's generated ball growing in a box, the box made smaller so the ball soon fills it: many pairs
    close in, steps cut by CCD."""
    d = _ball_in_box(f"pressed_ball_la{lookahead:g}", 0.4, 6)
    d["time"]["steps"] = 6
    d["solver"].update({"check_every_iterate": True, "contact_lookahead": lookahead})
    d["objects"][1]["generate"].update({"lo": [-0.4] * 3, "hi": [0.4] * 3})
    return d


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("lookahead")
    return {la: simulate(scene_from_dict(_pressed_ball(la)), out / f"la{la:g}", progress=False) for la in (0.0, 3.0)}


def test_lookahead_is_used_and_every_iterate_is_certified(runs):
    res = runs[3.0]
    recs = res.step_records
    assert sum(r["lookahead_iterations"] for r in recs) > 0, "the scene never cut a step short: it tests nothing"
    assert all(r["certificate"]["ok"] for r in recs)  # every iterate was checked too (check_every_iterate)
    assert res.summary["nonconverged_steps"] == 0


def test_steps_stop_on_the_exact_decrement(runs):
    for r in runs[3.0].step_records:
        assert r["converged"]
        # the decrement that stopped the step is the last one recorded, and it came from an exact matrix: an
        # iteration that saw the look-ahead is never the last (it hands the verdict to the next iteration)
        assert r["decrements"][-1] <= 0.5
        assert r["lookahead_iterations"] < r["newton_iterations"]


def test_same_shapes_within_the_stopping_tolerance(runs):
    # both runs meet the same stopping rule, so their growth ends equally far: the fill of the box agrees to
    # within what a Newton tolerance of 0.5·√h in the max norm allows on this coarse ball (a few percent)
    off, on = runs[0.0].summary["fill_fraction"], runs[3.0].summary["fill_fraction"]
    assert on == pytest.approx(off, abs=0.03)
    assert runs[0.0].step_records[-1]["lookahead_iterations"] == 0


@pytest.mark.parametrize("bad", [0.5, 1.0, -2.0, "3"])
def test_lookahead_setting_is_checked(bad):
    d = _pressed_ball(0.0)
    d["solver"]["contact_lookahead"] = bad
    with pytest.raises(SceneError, match="contact_lookahead"):
        scene_from_dict(d)


def test_integer_lookahead_is_accepted():
    d = _pressed_ball(0.0)
    d["solver"]["contact_lookahead"] = 3
    assert scene_from_dict(d).solver.contact_lookahead == 3.0


def test_a_lookahead_with_nothing_to_add_changes_nothing(tmp_path):
    # the ipctk barrier has no look-ahead blocks: the setting may switch the look-ahead on, but an iteration whose
    # matrix got no extra block is exact, so it counts as none and its "converged" verdict stands
    steps = {}
    for la in (0.0, 3.0):
        d = _pressed_ball(la)
        d["time"]["steps"] = 4
        d["solver"]["check_every_iterate"] = False
        d["contact"]["barrier"] = "ipctk"
        recs = simulate(scene_from_dict(d), tmp_path / f"la{la:g}", progress=False).step_records
        assert all(r["lookahead_iterations"] == 0 for r in recs)
        steps[la] = [r["newton_iterations"] for r in recs]
    assert steps[3.0] == steps[0.0]


def test_lookahead_only_follows_a_cut_step(runs):
    # the look-ahead is on only in an iteration right after an accepted move that CCD cut below half the Newton
    # step: never more look-ahead iterations in a step than such cut moves before its last iteration
    for r in runs[3.0].step_records:
        cut = sum(1 for a, c in zip(r["alphas"][:-1], r["ccd_alphas"][:-1], strict=True) if a > 0 and c < 0.5)
        assert r["lookahead_iterations"] <= cut


@pytest.mark.parametrize(
    ("setting", "compiled", "shells", "reach"),
    [("auto", True, False, 2.0), ("auto", True, True, 0.0), ("auto", False, False, 0.0), (3.0, False, True, 3.0)],
)
def test_auto_reach(setting, compiled, shells, reach):
    # "auto": on (reach 2) for volumes with the compiled barrier, off where a shell deforms or the barrier is
    # ipctk's; a number is taken as given
    assert contact_lookahead_reach(setting, compiled, shells) == reach


def test_auto_is_the_default_and_resolves_per_scene():
    d = _pressed_ball(0.0)
    del d["solver"]["contact_lookahead"]
    scene = scene_from_dict(d)
    assert scene.solver.contact_lookahead == "auto"
    assert build_scene(scene).newton.contact_lookahead == 2.0
    d["contact"]["barrier"] = "ipctk"
    assert build_scene(scene_from_dict(d)).newton.contact_lookahead == 0.0


@pytest.mark.parametrize("chunk", [1, 5, 10_000])
def test_block_stream_is_the_two_sets_a_range_at_a_time(chunk):
    # the active set's blocks, then the look-ahead set's (activation reach·d̂, stiffness share·κ), numbered one after
    # the other and computed a range at a time (ranges may straddle the two sets); the same kernel on views of the
    # same inputs, so equal bit for bit to each set computed whole
    x, surf, nd = stacked(0.02, 0.0, 4)  # two stacked boxes 0.02 apart, the upper one moving down by 0.015
    cm = ContactModel(x, surf, nd, dhat=0.025, kappa=3.0)
    y = x.copy()
    y[x[:, 2] > 1.01, 2] -= 0.015
    ev = cm.evaluate(x)
    vs = cm.surface_positions(x)
    vmap = np.arange(vs.shape[0], dtype=np.int64)
    cand = cm.sweep_candidates(x, y)  # as the Newton loop passes them: the sweep of the move CCD cut
    stream = cm.hessian_block_stream(ev, vmap, (3.0, 0.01, cand))
    a_bv, a_blocks = cm.hessian_blocks(ev, vmap)
    m, n_ahead = a_bv.shape[0], stream.n_ahead
    assert m > 0 and n_ahead >= m and len(stream) == m + n_ahead  # the wider set holds the active pairs
    blocks = np.empty((len(stream), 12, 12))
    buffer = np.empty((chunk, 12, 12))
    for c0 in range(0, len(stream), chunk):
        c1 = min(len(stream), c0 + chunk)
        blocks[c0:c1] = stream.blocks(c0, c1, buffer)
    bv = stream.block_verts
    ahead = cb.build_collision_set(vs, cm._edges, cm._faces, cand[0], cand[1], 3.0 * cm.dhat, cm._edge_rest_len2)
    l_bv, l_blocks = cb.barrier_hessian_blocks(ahead, vs, 3.0 * cm.dhat, 0.01 * cm.kappa, vmap, True)
    # only each block's leading 3n × 3n belongs to its n vertices (the rest is never read): compare those entries
    for got, want in [((bv[:m], blocks[:m]), (a_bv, a_blocks)), ((bv[m:], blocks[m:]), (l_bv, l_blocks))]:
        for g, w in zip(cb.blocks_to_coo(*got), cb.blocks_to_coo(*want), strict=True):
            np.testing.assert_array_equal(g, w)
    # κ = 0 or no candidates: the active blocks alone
    assert cm.hessian_block_stream(ev, vmap, (3.0, 0.01, None)).n_ahead == 0
    assert len(cm.hessian_block_stream(ev, vmap)) == m
