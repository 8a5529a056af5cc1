"""§4.3 Dirichlet targets and §4.5 handles / kinematic obstacles, end to end and in parts.

Scenes are small (a 20×2×2 beam, a thin slab); every collision scene checks every accepted Newton iterate
with the independent certificate (``check_every_iterate``)."""

from __future__ import annotations

import numpy as np
import pytest

from idp.api import simulate
from idp.errors import IntersectingInputError, SceneError
from idp.mesh.placement import rotation_matrix
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict
from idp.stepper.dirichlet import DirichletTargets
from idp.stepper.motions import Keyframe, Keyframes, Rotate, Translate

H = 0.04**2
BEAM = {"shape": "tet_box", "lo": [-0.5, -0.05, -0.05], "hi": [0.5, 0.05, 0.05], "resolution": [20, 2, 2]}
LEFT = {"box": [[0, 0, 0], [0.02, 1, 1]], "relative": True}
RIGHT = {"box": [[0.98, 0, 0], [1, 1, 1]], "relative": True}


def beam_scene(handles, *, steps=5, extra_objects=(), fixed=True, **top):
    obj = {
        "name": "beam",
        "generate": BEAM,
        "material": {"youngs_modulus": 1e5, "poisson_ratio": 0.3},
        "handles": handles,
    }
    if fixed:
        obj["fixed"] = [LEFT]
    d = {
        "name": "beam",
        "time": {"h": H, "steps": steps},
        "solver": {"newton_tol": 1e-2, "check_every_iterate": True},
        "contact": {"dhat": 1e-3},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [obj, *extra_objects],
    }
    d.update(top)
    return scene_from_dict(d)


def certified(res):
    for r in res.step_records:
        assert r["certificate"]["intersection_free"] and r["certificate"]["inversion_free"], r["step"]
    return res.step_records


# -- §4.3: quota, penalty, hold ------------------------------------------------------------------------


def test_quota_reaches_the_target_by_subdividing_the_remaining_path(tmp_path):
    offset = [0.0, 0.3, 0.0]
    s = beam_scene([{"name": "tip", "select": RIGHT, "motion": {"type": "targets", "offset": offset, "quota": 5}}])
    built = build_scene(s)
    tip = built.system.conditions[0].handles[0]
    x0 = built.system.x[tip.vertices].copy()
    res = simulate(s, tmp_path, progress=False)
    recs = certified(res)
    assert all(r["dirichlet"]["met"] for r in recs)
    # after the quota the tip sits exactly on the final target; before it, on the subdivided path
    np.testing.assert_allclose(res.x[tip.vertices], x0 + offset, rtol=0, atol=1e-12)
    assert [r["dirichlet"]["residual_max"] for r in recs] == [0.0] * 5


def test_penalty_doubles_near_convergence_and_is_dropped_once_the_targets_are_met():
    masses = np.ones(4)
    bc = DirichletTargets(masses, 2, tolerance=1e-6, kappa_initial=10.0)
    x = np.zeros((4, 2))
    bc.set_targets(np.array([1, 2]), np.array([[1.0, 0.0], [0.0, 1.0]]))
    x1 = bc.begin(x, lambda x, P: 0.5)  # only half of the move is feasible
    np.testing.assert_allclose(x1[[1, 2]], [[0.5, 0.0], [0.0, 0.5]])
    assert not bc.met and not bc.settled and bc.penalty_value(x1) > 0
    np.testing.assert_allclose(bc.penalty_hessian_diagonal().reshape(4, 2)[[1, 2]], 10.0)
    # far from convergence: nothing changes; near convergence with targets unmet: κ_B doubles
    assert bc.after_iterate(x1, False, lambda x, P: 1.0) == (x1, False)
    x2 = x1.copy()
    x2[[1, 2]] = [[0.9, 0.0], [0.0, 0.9]]
    _, changed = bc.after_iterate(x2, True, lambda x, P: 1.0)
    assert changed and bc.kappa == 20.0 and bc.doublings == 1
    # within tolerance: snapped exactly onto the targets, held, penalty gone
    x3 = x2.copy()
    x3[[1, 2]] = [[1.0 - 1e-7, 0.0], [0.0, 1.0]]
    x4, changed = bc.after_iterate(x3, False, lambda x, P: 1.0)
    assert changed and bc.met and bc.settled
    np.testing.assert_array_equal(x4[[1, 2]], bc.targets)  # a copy of the targets: identity by construction
    assert bc.penalty_value(x4) == 0.0 and not bc.penalty_hessian_diagonal().any()
    held = bc.held_dofs().reshape(4, 2)
    assert held[[1, 2]].all() and not held[[0, 3]].any()


def test_total_progress_rule_holds_the_handles_where_they_are_once_together_99_percent_of_the_way():
    """The authors' rule: met once 1 − √(Σ‖x − x̃‖² / Σ‖x⁰ − x̃‖²) ≥ 0.99, however far one vertex lags; then held
    where they are (not snapped) and the penalty dropped. A bound vertex with no move is held exactly from the
    start."""
    bc = DirichletTargets(np.ones(4), 2, tolerance=1e-6, kappa_initial=10.0, met_rule="total_progress")
    x = np.zeros((4, 2))
    bc.set_targets(np.array([0, 1, 2]), np.array([[10.0, 0.0], [0.0, 0.1], [0.0, 0.0]]))  # 2: a fixed handle
    x1 = bc.begin(x, lambda x, P: 0.0)
    assert not bc.settled and bc.penalty_value(x1) > 0
    held = bc.held_dofs().reshape(4, 2)
    assert held[2].all() and not held[[0, 1, 3]].any()
    x2 = x1.copy()
    x2[[0, 1]] = [[9.5, 0.0], [0.0, 0.05]]  # 95 % of the way: pulled on
    assert bc.after_iterate(x2, False, lambda x, P: 1.0) == (x2, False)
    x3 = x1.copy()
    x3[[0, 1]] = [[9.99, 0.0], [0.0, 0.01]]  # together 99.1 % of the way, vertex 1 only 10 % of its own
    x4, changed = bc.after_iterate(x3, False, lambda x, P: 1.0)
    assert changed and bc.met and bc.settled and x4 is x3  # held where they are, not snapped
    assert bc.penalty_value(x4) == 0.0 and bc.held_dofs().reshape(4, 2)[[0, 1, 2]].all()
    # the default rule asks every vertex to be within the tolerance: the same iterate is not met
    d = DirichletTargets(np.ones(4), 2, tolerance=1e-6, kappa_initial=10.0)
    d.set_targets(np.array([0, 1, 2]), np.array([[10.0, 0.0], [0.0, 0.1], [0.0, 0.0]]))
    d.begin(x, lambda x, P: 0.0)
    assert not d.after_iterate(x3, False, lambda x, P: 1.0)[1] and not d.met
    with pytest.raises(ValueError, match="met_rule"):
        DirichletTargets(np.ones(2), 1, tolerance=1e-6, met_rule="some")
    with pytest.raises(ValueError, match="met_progress"):
        DirichletTargets(np.ones(2), 1, tolerance=1e-6, met_rule="total_progress", met_progress=1.0)


def _one_handle(target: float = 1.0, **settings) -> tuple[DirichletTargets, np.ndarray]:
    """Two 1D vertices of unit mass, vertex 0 bound to ``target`` from x = 0 (no feasible move: the penalty pulls)."""
    bc = DirichletTargets(np.ones(2), 1, **settings)
    x = np.zeros((2, 1))
    bc.set_targets(np.array([0]), np.array([[target]]))
    return bc, bc.begin(x, lambda x, P: 0.0)


def test_blocked_targets_stop_the_doubling():
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    x[0] = 0.5
    assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]  # first doubling
    x[0] = 0.502  # less than 1 % closer after the doubling: one more doubling to see whether gains grow
    assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]
    x[0] = 0.503  # an even smaller gain: blocked
    assert bc.after_iterate(x, True, lambda x, P: 0.0) == (x, False)
    assert bc.settled and not bc.met and bc.report(x, 1e-3)["blocked"] and bc.doublings == 2


def test_blocked_steps_do_not_hand_their_doublings_on():
    """A handle blocked step after step (a tool jammed on an obstacle): the doublings that brought it no closer are
    dropped between steps, so κ_B does not compound from step to step; a doubling that helped is kept."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    start = bc.kappa
    for k in range(5):  # each step: doublings with shrinking gains, then blocked
        x[0] = 0.5
        assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]
        x[0] = 0.502
        assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]
        x[0] = 0.503
        assert not bc.after_iterate(x, True, lambda x, P: 0.0)[1] and bc.settled and not bc.met
        assert bc.kappa == 4.0 * start  # raised within the step ...
        bc.relax()
        assert bc.kappa == max(1.0, 0.5 * start)  # ... but not handed on
        bc.set_targets(np.array([0]), np.array([[1.0 + 1e-3 * (k + 1)]]))  # the tool driven on, still jammed
        x = bc.begin(np.zeros((2, 1)), lambda x, P: 0.0)
        assert not bc.settled
        start = bc.kappa
    # a doubling that brought the handle min_progress closer is kept, even when the step then ends blocked
    x[0] = 0.5
    assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]  # κ 1 → 2
    x[0] = 0.75  # half the residual: that doubling helped
    assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]  # κ 2 → 4
    x[0] = 0.751  # a gain below min_progress, and smaller than the one before: blocked at κ 4
    assert not bc.after_iterate(x, True, lambda x, P: 0.0)[1] and bc.settled and not bc.met and bc.kappa == 4.0
    bc.relax()
    assert bc.kappa == 1.0  # κ_B 2, which brought the handle closer, halved between steps (4 would give 2)


def _jam(bc: DirichletTargets, x: np.ndarray) -> None:
    """Doublings with shrinking gains at near-converged iterates: the step ends blocked."""
    for pos in (0.5, 0.502):
        x[0] = pos
        assert bc.after_iterate(x, True, lambda x, P: 0.0)[1]
    x[0] = 0.503
    assert not bc.after_iterate(x, True, lambda x, P: 0.0)[1] and bc.settled and not bc.met


def test_the_targets_a_step_ended_blocked_on_are_held_from_the_start_of_the_next():
    """The same targets, still with no room towards them: the next step neither moves the bound vertices (the
    first move, unchecked, would only press the blocking pair closer) nor turns the penalty on; they are held
    where they are and the step is reported blocked."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    _jam(bc, x)
    bc.relax()
    room = 1e-7  # the feasible move: 1e-7 of the way (below the tolerance)
    moved = bc.begin(x.copy(), lambda x, P: room)
    assert np.array_equal(moved, x)  # no first move
    assert bc.settled and not bc.met and bc.penalty_value(moved) == 0.0
    assert bc.held_dofs()[0] and not bc.held_dofs()[1]  # the bound vertex held, the free one optimised
    report = bc.report(moved, None)
    assert report["held_blocked"] and report["blocked"] and not report["met"]
    assert bc.after_iterate(moved, True, lambda x, P: room) == (moved, False)
    # ended blocked again: the step after holds them too, also when the targets moved a little less than the
    # tolerance (an incremental handle's targets follow the vertices)
    bc.relax()
    bc.set_targets(np.array([0]), np.array([[1.0 + 0.9e-6]]))
    assert np.array_equal(bc.begin(moved.copy(), lambda x, P: room), moved) and bc.report(moved, None)["held_blocked"]


@pytest.mark.parametrize("change", ["targets", "room", "met"])
def test_blocked_targets_are_not_held_when_something_changed(change):
    """Targets moved by the tolerance or more (an animation's next frame), a feasible move at least the tolerance
    long, or a last step that met its targets: the step starts as §4.3 says (the feasible first move, then the
    penalty)."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    if change == "met":
        bc.begin(x, lambda x, P: 1.0)  # on target at once
    else:
        _jam(bc, x)
    bc.relax()
    if change == "targets":
        bc.set_targets(np.array([0]), np.array([[1.0 + 2e-6]]))
    room = 1e-3 if change == "room" else 1e-7
    start = x.copy()
    moved = bc.begin(start, lambda x, P: room)
    assert not bc.settled and not bc.report(moved, None)["held_blocked"]
    assert moved[0, 0] == pytest.approx(start[0, 0] + room * (bc.targets[0, 0] - start[0, 0]), rel=1e-12)
    assert bc.penalty_value(moved) > 0.0


def test_checkpoint_keeps_the_targets_a_step_ended_blocked_on():
    """A resumed run holds blocked targets from the same step as the uninterrupted one."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    _jam(bc, x)
    bc.relax()
    st = bc.state()
    assert set(st) == {"blocked_vertices", "blocked_targets"}
    fresh, _ = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.01)
    fresh.load_state(st)
    fresh.begin(x.copy(), lambda x, P: 1e-7)
    assert fresh.report(x, None)["held_blocked"]
    fresh.load_state({})  # a checkpoint from a step that did not end blocked (or from before this was kept)
    fresh.begin(x.copy(), lambda x, P: 1e-7)
    assert not fresh.report(x, None)["held_blocked"]
    with pytest.raises(ValueError, match="blocked_targets"):
        fresh.load_state({"blocked_vertices": np.array([0]), "blocked_targets": np.zeros((2, 1))})


def test_a_blocked_snap_is_retried_until_the_penalty_brings_the_vertices_closer():
    """The snap's last bit would reach a free body (within CCD's margin of the target while the residual is above
    2e-5): the penalty stays on while Newton converges and κ_B doubles; the snap goes through once the residual
    is small enough, so the bound vertex ends exactly on its target."""
    bc, x = _one_handle(tolerance=1e-4, kappa_initial=1.0)
    feasible = lambda x, P: 1.0 if abs(P[0, 0]) < 2e-5 else 0.5  # noqa: E731
    x[0] = 1.0 + 6e-5
    assert bc.after_iterate(x, False, feasible) == (x, False)  # not near convergence: Newton goes on
    assert not bc.settled and bc.penalty_value(x) > 0
    x, changed = bc.after_iterate(x, True, feasible)  # converged with the snap blocked: κ_B doubles
    assert changed and bc.kappa == 2.0 and not bc.settled
    x[0] = 1.0 + 3e-5
    assert bc.after_iterate(x, True, feasible)[1] and bc.kappa == 4.0
    x[0] = 1.0 + 1.5e-5  # now within the free body's gap of its target
    x, changed = bc.after_iterate(x, False, feasible)
    assert changed and bc.met and x[0, 0] == 1.0


def test_a_snap_that_the_penalty_cannot_bring_closer_is_held_within_the_tolerance():
    """A doubling that leaves the residual where it was (the vertex's own input crosses something there): held
    within the tolerance, met, after one retry."""
    bc, x = _one_handle(tolerance=1e-4, kappa_initial=1.0)
    blocked = lambda x, P: 0.5  # noqa: E731
    x[0] = 1.0 + 6e-5
    assert bc.after_iterate(x, True, blocked)[1] and bc.kappa == 2.0
    x, changed = bc.after_iterate(x, True, blocked)  # no closer after the doubling
    assert changed and bc.met and bc.settled and x[0, 0] == 1.0 + 6e-5 and bc.kappa == 2.0
    assert bc.penalty_value(x) == 0.0


def test_growing_small_gains_keep_doubling():
    """Against an elastic stiffness K ≫ κ_B the residual shrinks by κ/(K + 2κ) per doubling: small, but growing
    with κ — not a block."""
    K, kappa0, target = 1e4, 1.0, 1.0
    bc, x = _one_handle(target, tolerance=1e-6, kappa_initial=kappa0, min_progress=0.1)
    for _ in range(12):  # the penalised minimum of K/2 x² + κ/2 (x − 1)² for the current κ
        x[0] = bc.kappa / (K + bc.kappa) * target
        _, changed = bc.after_iterate(x, True, lambda x, P: 0.0)
        assert changed and not bc.settled
    assert bc.doublings == 12


def test_multiplier_meets_targets_that_the_capped_penalty_cannot():
    """κ_B at its cap against an elastic stiffness K ≫ κ_B, nothing in contact: augmented-Lagrangian updates
    λ ← λ − κ m (x − x̃) carry the handle onto its target (the penalised minimum alone stays at κ/(K + κ))."""
    K, target = 4.0, 1.0  # each update shrinks the residual by K / (K + κ) = 0.8: 21 updates reach 1e-2
    bc, x = _one_handle(target, tolerance=1e-2, kappa_initial=1.0, max_doublings=0)
    for _ in range(bc.max_multiplier_updates + 1):
        # the minimum of K/2 x² + κ/2 (x − 1)² − λ (x − 1): the gradient in x is zero there
        x[0] = (bc.kappa * target + _multiplier(bc)) / (K + bc.kappa)
        g = K * x[0, 0] + bc.penalty_gradient(x)[0]
        assert abs(g) < 1e-12
        x, changed = bc.after_iterate(x, True, lambda x, P: 1.0, in_contact=False)
        if bc.met:
            break
        assert changed
    assert bc.met and x[0, 0] == target and 10 <= bc.multiplier_updates < bc.max_multiplier_updates
    assert bc.report(x, 1e-3)["multiplier_updates"] == bc.multiplier_updates


def test_no_multiplier_update_in_contact():
    """Against contact the capped penalty is a block, as before: the multiplier would only press the gap shut."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, max_doublings=0)
    x[0] = 0.2
    assert bc.after_iterate(x, True, lambda x, P: 0.0, in_contact=True) == (x, False)
    assert bc.settled and not bc.met and bc.multiplier_updates == 0


def _multiplier(bc: DirichletTargets) -> float:
    """λ of the single penalised vertex (the linear term of the penalty: its gradient at x = x̃ is −λ)."""
    at_target = np.array([[1.0], [0.0]])
    return -float(bc.penalty_gradient(at_target)[0])


def test_stalled_targets_are_frozen_where_they_are():
    """Away from convergence, stall_iterations iterates without min_progress gain hold the handle in place."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, stall_iterations=5)
    x[0] = 0.5
    for k in range(5):  # the first call sets the best residual, four more without progress
        assert bc.after_iterate(x, False, lambda x, P: 0.0, contact_limited=True) == (x, False), k
        x[0] += 0.001  # creeping: under 10 % of the residual per iterate
    x_out, changed = bc.after_iterate(x, False, lambda x, P: 0.0, contact_limited=True)
    assert changed and x_out is x  # frozen where it is: no move
    assert bc.settled and not bc.met
    rep = bc.report(x, 1e-3)
    assert rep["blocked"] and rep["frozen_after_stall"] and rep["residual_max"] == pytest.approx(1.0 - x[0, 0])
    assert bc.held_dofs()[0] and not bc.held_dofs()[1] and bc.penalty_value(x) == 0.0


def test_cut_steps_that_keep_growing_are_not_a_stall():
    """A handle pressed onto a pair squeezed to ~1e-14 advances a sliver per iterate while the barrier opens the
    pair (Kick frame 52): iterates whose CCD-cut step is STEP_GROWTH times longer than every earlier cut step do
    not count as stalled; once the cut steps stop growing, the stall is counted again."""
    from idp.stepper.dirichlet import STEP_GROWTH

    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, stall_iterations=5)
    x[0] = 0.5
    fraction = 1e-9
    for k in range(12):  # no residual progress, but each cut step twice the last
        assert bc.after_iterate(x, False, lambda x, P: 0.0, contact_limited=True, ccd_fraction=fraction) == (
            x,
            False,
        ), k
        fraction *= 2.0 * STEP_GROWTH / 1.5
    assert not bc.settled and not bc.frozen
    fraction /= 2.0  # the last cut step's length, from now on
    for _ in range(5):  # now the cut steps stay as they are: five stalled iterates freeze the handle
        _, changed = bc.after_iterate(x, False, lambda x, P: 0.0, contact_limited=True, ccd_fraction=fraction)
    assert changed and bc.frozen and bc.settled and not bc.met


def test_without_contact_shrinking_gains_keep_doubling():
    """Only contact blocks a target: with no pair within d̂, κ_B doubles on whatever the gains do."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, min_progress=0.1)
    for k in range(6):
        x[0] = 0.5 + 0.001 * k  # gains of ~0.2 %, not growing
        _, changed = bc.after_iterate(x, True, lambda x, P: 0.0, in_contact=False)
        assert changed and not bc.settled, k
    assert bc.doublings == 6


def test_slow_newton_without_contact_is_not_taken_for_a_stall():
    """Iterates that CCD did not cut (Newton creeping towards the penalised minimum of a stiff energy) never
    freeze the handles: the §4.3 doubling near convergence decides."""
    bc, x = _one_handle(tolerance=1e-6, kappa_initial=1.0, stall_iterations=5)
    x[0] = 0.5
    for k in range(20):  # nothing cut, or cut by CCD with no pair within d̂
        assert bc.after_iterate(x, False, lambda x, P: 0.0, contact_limited=k % 2 == 1, in_contact=False) == (
            x,
            False,
        ), k
        x[0] += 0.001
    assert not bc.settled and not bc.frozen and bc.penalty_value(x) > 0
    assert bc.after_iterate(x, True, lambda x, P: 0.0)[1] and bc.doublings == 1


def tip_into_block(*, steps: int, quota: int = 1, **top) -> dict:
    """The beam's tip pulled 0.3 up by a handle (reached by its quota, then unchanged) into a box obstacle over it,
    which blocks it 0.23 short."""
    block = {
        "name": "block",
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [0.3, 0.12, -0.2], "hi": [0.7, 0.4, 0.2], "resolution": 2},
    }
    tip = {"name": "tip", "select": RIGHT, "motion": {"type": "targets", "offset": [0.0, 0.3, 0.0], "quota": quota}}
    return beam_scene([tip], steps=steps, extra_objects=[block], **top)


def test_handle_pushed_into_an_obstacle_keeps_injectivity_and_reports_the_residual(tmp_path):
    s = tip_into_block(steps=3, quota=2)
    res = simulate(s, tmp_path, progress=False)
    recs = certified(res)
    last = recs[-1]["dirichlet"]
    assert not last["met"]  # blocked, or still pulling when the step ends: reported either way
    # the tip stops below the block (y = 0.12), 0.3 - 0.07 short of its target
    assert last["residual_max"] == pytest.approx(0.23, abs=0.01)
    assert last["residual_max_over_dhat"] == pytest.approx(last["residual_max"] / 1e-3)
    assert res.summary["steps_with_unmet_targets"] == 3
    assert min(r["min_distance"] for r in recs) > 0


def test_a_handle_held_blocked_step_after_step_keeps_its_gap_and_resumes_the_same(tmp_path):
    """A tip pushed into a block, its target reached by the quota and then unchanged: from step 2 the blocked tip is
    held where step 1 left it, so the steps are short and the gap the penalty had pressed to ~1e-9 opens again
    (measured before the rule: steps 2–6 took 32–38 iterations each, the gap back at 1.7e-9 every other step).
    A run resumed between held steps gives the uninterrupted run's positions."""
    whole = simulate(tip_into_block(steps=6), tmp_path / "whole", progress=False)
    recs = certified(whole)
    first, held = recs[0], recs[1:]
    assert first["dirichlet"]["blocked"] and not first["dirichlet"]["held_blocked"]
    assert all(r["dirichlet"]["held_blocked"] and not r["dirichlet"]["met"] for r in held)
    assert all(r["newton_iterations"] <= 10 for r in held)
    assert min(r["min_distance"] for r in held) > 100 * first["min_distance"]
    simulate(tip_into_block(steps=3), tmp_path / "split", progress=False)
    resumed = simulate(tip_into_block(steps=6), tmp_path / "split", progress=False, resume=True)
    assert [r["dirichlet"]["held_blocked"] for r in resumed.step_records[3:]] == [True] * 3
    np.testing.assert_allclose(resumed.x, whole.x, rtol=0, atol=1e-10)


def test_unmet_targets_can_stop_the_run(tmp_path):
    s = tip_into_block(steps=3, dirichlet={"on_unmet": "error"})
    from idp.errors import SolverError

    with pytest.raises(SolverError, match="Dirichlet targets unmet"):
        simulate(s, tmp_path, progress=False)
    assert (tmp_path / "checkpoint.npz").exists()  # the certified step is kept, resumable


# -- §4.5: scripted handles and kinematic obstacles -------------------------------------------------


def test_rotated_handles_reach_their_targets(tmp_path):
    # both caps turn about z through the beam's centre line ends: the beam bends into an arc
    steps, rate = 5, 90.0  # 90°/s · 5 · 0.04 s = 18°
    left = {
        "name": "l",
        "select": LEFT,
        "motion": {"type": "rotate", "axis": [0, 0, 1], "center": [-0.5, 0, 0], "degrees_per_second": -rate},
    }
    right = {
        "name": "r",
        "select": RIGHT,
        "motion": {"type": "rotate", "axis": [0, 0, 1], "center": [0.5, 0, 0], "degrees_per_second": rate},
    }
    s = beam_scene([left, right], steps=steps, fixed=False)
    built = build_scene(s)
    hs = built.system.conditions[0].handles
    X = [built.system.x[h.vertices].copy() for h in hs]
    res = simulate(s, tmp_path, progress=False)
    recs = certified(res)
    assert all(r["dirichlet"]["met"] for r in recs)
    for h, X0, sign, c in zip(hs, X, (-1, 1), (-0.5, 0.5), strict=True):
        R = rotation_matrix((0, 0, 1), sign * rate * steps * 0.04)
        want = (X0 - [c, 0, 0]) @ R.T + [c, 0, 0]
        np.testing.assert_allclose(res.x[h.vertices], want, rtol=0, atol=1e-9)


def test_fast_kinematic_obstacle_does_not_tunnel(tmp_path):
    # a plate moving 0.4 per step (8× the slab's thickness) hits a slab whose top is fixed
    slab = {
        "name": "slab",
        "generate": {"shape": "tet_box", "lo": [-0.3, 0.0, -0.3], "hi": [0.3, 0.05, 0.3], "resolution": [4, 1, 4]},
        "material": {"youngs_modulus": 1e4, "poisson_ratio": 0.3},
        "fixed": [{"box": [[0, 0.9, 0], [1, 1, 1]], "relative": True}],
    }
    plate = {
        "name": "plate",
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [-0.1, -0.2, -0.1], "hi": [0.1, -0.15, 0.1], "resolution": 1},
        "motion": {"motion": {"type": "translate", "velocity": [0.0, 10.0, 0.0]}},
    }
    d = {
        "time": {"h": H, "steps": 2},
        "solver": {"check_every_iterate": True},
        "contact": {"dhat": 1e-3},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [slab, plate],
    }
    res = simulate(scene_from_dict(d), tmp_path, progress=False)
    recs = certified(res)
    assert recs[-1]["dirichlet"]["blocked"] and not recs[-1]["dirichlet"]["met"]
    plate, slab = res.x[res.parts[1].vertex_ids], res.x[res.parts[0].vertex_ids]
    above = slab[(np.abs(slab[:, 0]) <= 0.1) & (np.abs(slab[:, 2]) <= 0.1)]
    assert above.size and plate[:, 1].max() < above[:, 1].min()  # below the slab it pushes: no tunnelling
    assert plate[:, 1].max() - plate[:, 1].min() == pytest.approx(0.05, rel=1e-9)  # moved rigidly


def press_ball_onto_floor(tmp_path, *, speed, steps, poisson_ratio, solver, dirichlet=None):
    """A rigid plate moving down ``speed`` per unit time onto a ball resting on a floor (all generated); returns
    the run's result and its certified step records."""
    ball = {
        "name": "ball",
        "generate": {"shape": "ball", "radius": 0.3, "resolution": 2},
        "translate": [0, 0.302, 0],
        "material": {"youngs_modulus": 1e4, "poisson_ratio": poisson_ratio},
    }
    floor = {
        "name": "floor",
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [-1, -0.1, -1], "hi": [1, 0.0, 1], "resolution": 1},
    }
    plate = {
        "name": "plate",
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [-0.5, 0.62, -0.5], "hi": [0.5, 0.7, 0.5], "resolution": 1},
        "motion": {"motion": {"type": "translate", "velocity": [0.0, -speed, 0.0]}},
    }
    d = {
        "time": {"h": H, "steps": steps},
        "solver": {"check_every_iterate": True, **solver},
        "contact": {"dhat": 1e-3},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [ball, floor, plate],
        **({"dirichlet": dirichlet} if dirichlet else {}),
    }
    res = simulate(scene_from_dict(d), tmp_path, progress=False)
    return res, certified(res)


def test_a_kinematic_press_squeezes_a_ball_onto_a_floor(tmp_path):
    # a rigid plate moving down 0.02 per step onto a ball resting on a floor: the ball cannot move away, so the
    # plate advances only as the ball is compressed. With the plate as one Newton DOF the targets are met every
    # step; as a tool moved between Newton solves it stalled (blocked after one step, gaps ~1e-6 for d̂ = 1e-3).
    steps = 5
    res, recs = press_ball_onto_floor(tmp_path, speed=0.5, steps=steps, poisson_ratio=0.3, solver={})
    assert all(r["dirichlet"]["met"] and not r["dirichlet"]["blocked"] for r in recs)
    assert min(r["min_distance"] for r in recs) > 1e-5  # no gap crushed towards 0 (d̂ = 1e-3)
    by_name = {p.name: p for p in res.parts}
    plate_y = res.x[by_name["plate"].vertex_ids][:, 1]
    ball_y = res.x[by_name["ball"].vertex_ids][:, 1]
    assert plate_y.min() == pytest.approx(0.62 - 0.02 * steps, abs=1e-9)  # the press went all the way, rigidly
    assert plate_y.max() - plate_y.min() == pytest.approx(0.08, abs=1e-9)
    assert ball_y.min() > 0.0 and ball_y.max() < plate_y.min()  # squeezed between them, touching neither
    assert plate_y.min() - ball_y.max() < 1e-3 and ball_y.min() < 1e-3  # in contact with both (within d̂)


def test_the_authors_rule_lets_a_pressing_tool_stop_99_percent_of_the_way(tmp_path):
    # met_rule = "total_progress" (Fig. 22's vase): a tool pressing a ball onto a floor counts as there once it has
    # come 99 % of its step's move, and is held there, rigid, instead of being pressed on until within the
    # tolerance. Every iterate is checked (check_every_iterate) and every frame certified.
    steps, speed = 4, 1.5
    move = speed * 0.04  # the plate's move per step (dt = 0.04)
    res, recs = press_ball_onto_floor(
        tmp_path, speed=speed, steps=steps, poisson_ratio=0.4, solver={}, dirichlet={"met_rule": "total_progress"}
    )
    assert all(r["dirichlet"]["met"] and not r["dirichlet"]["blocked"] for r in recs)
    assert min(r["min_distance"] for r in recs) > 1e-5
    short = [r["dirichlet"]["residual_max"] for r in recs]
    assert max(short) > 0.0  # the rule, not the per-vertex tolerance, ended some step
    assert max(short) <= 0.01 * move  # at least 99 % of the way (the plate's vertices lag alike)
    by_name = {p.name: p for p in res.parts}
    plate_y = res.x[by_name["plate"].vertex_ids][:, 1]
    assert plate_y.max() - plate_y.min() == pytest.approx(0.08, abs=1e-9)  # rigid
    # its targets are absolute (start + v t): the plate ends short of the last one by that step's shortfall only
    assert plate_y.min() - (0.62 - steps * move) == pytest.approx(short[-1], rel=1e-6)
    # the default rule presses on until the plate is on its targets, in more Newton iterations
    _, recs_e = press_ball_onto_floor(tmp_path / "each", speed=speed, steps=steps, poisson_ratio=0.4, solver={})
    assert all(r["dirichlet"]["met"] and r["dirichlet"]["residual_max"] == 0.0 for r in recs_e)
    assert sum(r["newton_iterations"] for r in recs) <= sum(r["newton_iterations"] for r in recs_e)


def test_a_fast_kinematic_press_with_contact_look_ahead_is_not_blocked(tmp_path):
    # the plate comes down 0.06 per step (a fifth of the ball's radius) with the contact look-ahead on. Its blocks
    # stiffen the ball's side of each pair just outside d̂, but a tool is coupled to the ball through the exact
    # contact Hessian only; with look-ahead in the tools' bordered system the plate pressed the ball without it
    # giving way: blocked from step 2, gaps crushed to ~1e-9 (Fig. 1's compress stage stalled the same way).
    steps = 4
    res, recs = press_ball_onto_floor(
        tmp_path, speed=1.5, steps=steps, poisson_ratio=0.4, solver={"contact_lookahead": 2}
    )
    assert all(r["dirichlet"]["met"] and not r["dirichlet"]["blocked"] for r in recs[1:])
    assert all(r["lookahead_iterations"] == 0 for r in recs[1:])  # a tool moved in every step
    assert min(r["min_distance"] for r in recs[1:]) > 1e-5
    by_name = {p.name: p for p in res.parts}
    plate_y = res.x[by_name["plate"].vertex_ids][:, 1]
    assert plate_y.min() == pytest.approx(0.62 - 0.06 * steps, abs=1e-9)


def test_motions():
    X = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    np.testing.assert_allclose(Translate(np.array([0.0, 0.0, 1.0])).targets(X, 0.5), X + np.array([0.0, 0.0, 0.5]))
    R = Rotate(90.0, np.zeros(3), np.array([0.0, 0.0, 1.0])).targets(X, 1.0)
    np.testing.assert_allclose(R, [[0.0, 1.0, 0.0], [-2.0, 0.0, 0.0]], atol=1e-15)
    k0 = Keyframe(0.0, np.zeros(3), np.zeros(3), np.ones(1))
    k1 = Keyframe(1.0, np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, np.pi / 2]), np.ones(1))
    kf = Keyframes([k0, k1], np.zeros(3))
    np.testing.assert_allclose(kf.targets(X, 0.5)[:, 2], 1.0)
    np.testing.assert_allclose(kf.targets(X, 2.0), [[0.0, 1.0, 2.0], [-2.0, 0.0, 2.0]], atol=1e-15)
    smooth = Keyframes([k0, k1], np.zeros(3), smooth=True)
    assert smooth.targets(X, 0.25)[0, 2] < kf.targets(X, 0.25)[0, 2]


# -- bad input ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("handles", "match"),
    [
        ([{"name": "a", "select": {"box": [[2, 2, 2], [3, 3, 3]]}}], r"objects\[0\]\.handles\[0\].*matches no vertex"),
        ([{"name": "a", "select": {"indices": [5, 100000]}}], r"index 100000 out of range"),
        ([{"name": "a", "select": LEFT}], r"pins"),
        (
            [
                {"name": "a", "select": RIGHT},
                {"name": "b", "select": RIGHT, "motion": {"type": "translate", "velocity": [0, 1, 0]}},
            ],
            r"handles 'beam\.a' and 'beam\.b' overlap",
        ),
    ],
)
def test_bad_handles_are_named(handles, match):
    with pytest.raises(SceneError, match=match):
        build_scene(beam_scene(handles))


def test_targets_file_with_the_wrong_vertex_count(tmp_path):
    f = tmp_path / "t.npy"
    np.save(f, np.zeros((3, 3)))
    h = [{"name": "tip", "select": RIGHT, "motion": {"type": "targets", "file": str(f)}}]
    with pytest.raises(SceneError, match=r"handles\[0\].*targets for 3 vertices but the selection has 9"):
        build_scene(beam_scene(h))


def test_schema_rejects_inconsistent_motions():
    with pytest.raises(SceneError, match="degrees_per_second"):
        beam_scene([{"name": "a", "select": RIGHT, "motion": {"type": "rotate", "axis": [0, 0, 1]}}])
    with pytest.raises(SceneError, match="axis"):
        beam_scene([{"name": "a", "select": RIGHT, "motion": {"type": "rotate", "degrees_per_second": 1.0}}])
    with pytest.raises(SceneError, match="end"):
        beam_scene([{"name": "a", "select": RIGHT, "start": 5, "end": 5}])


def test_kinematic_obstacle_starting_inside_a_body_is_refused():
    plate = {
        "name": "plate",
        "kind": "obstacle",
        "generate": {"shape": "box_surface", "lo": [-0.1, -0.2, -0.2], "hi": [0.1, 0.2, 0.2], "resolution": 1},
        "motion": {"motion": {"type": "translate", "velocity": [0.0, 1.0, 0.0]}},
    }
    with pytest.raises(IntersectingInputError):
        build_scene(beam_scene([], extra_objects=[plate]))


def test_targets_streamed_from_code(tmp_path):
    s = beam_scene([], steps=4)
    built = build_scene(s)
    x0 = built.system.x
    tip = np.flatnonzero(x0[:, 0] >= 0.49)

    def lift(step, x):  # the tip goes up 0.02 per step
        return tip, x0[tip] + [0.0, 0.02 * step, 0.0]

    res = simulate(s, tmp_path, progress=False, targets=lift)
    recs = certified(res)
    assert all(r["dirichlet"]["met"] for r in recs)
    np.testing.assert_allclose(res.x[tip], x0[tip] + [0.0, 0.08, 0.0], rtol=0, atol=1e-12)


def _loop_scene(contact: bool, steps: int = 28):
    # both caps swing up about z through (0, 0.06, 0) by 97.2° in 27 steps and hold: their targets overlap at
    # the top (each spans x ≈ ±0.05 there), so with the barrier they cannot both be met
    caps = [
        {
            "name": n,
            "select": sel,
            "end": 27,
            "motion": {"type": "rotate", "axis": [0, 0, 1], "center": [0, 0.06, 0], "degrees_per_second": s * 90.0},
        }
        for n, sel, s in (("l", LEFT, -1.0), ("r", RIGHT, 1.0))
    ]
    return beam_scene(
        caps,
        steps=steps,
        fixed=False,
        contact={"enabled": contact, "dhat": 1e-3},
        solver={"newton_tol": 1e-2, "check_every_iterate": contact},
    )


def test_without_the_barrier_intersections_are_counted_not_failed(tmp_path):
    res = simulate(_loop_scene(False), tmp_path / "off", progress=False)
    crossing = [r["certificate"]["intersecting_pairs"] for r in res.step_records]
    assert res.summary["all_certified"]  # locally injective only: reported, not a failure
    assert max(crossing) > 0 and crossing[0] == 0
    assert all(not r["certificate"]["guards_intersection"] for r in res.step_records)


@pytest.mark.slow
def test_with_the_barrier_the_same_loop_stays_intersection_free(tmp_path):
    res = simulate(_loop_scene(True), tmp_path / "on", progress=False)
    recs = certified(res)
    assert max(r["contacts"] for r in recs) > 0
    assert not recs[-1]["dirichlet"]["met"]  # the caps cannot pass each other


def test_resume_restores_handles_selected_during_the_run(tmp_path):
    # the tip handle is chosen on the shape at step 1 (after the first lift) and turns from then on
    lift = {"name": "lift", "select": RIGHT, "end": 1, "motion": {"type": "translate", "velocity": [0, 1.0, 0]}}
    turn = {
        "name": "turn",
        "select": {"sphere": {"center": [0.75, 0.5, 0.5], "radius": 0.06}, "relative": True},
        "select_on": "current",
        "start": 1,
        "motion": {"type": "rotate", "axis": [1, 0, 0], "center": [0.25, 0.02, 0], "degrees_per_second": 45.0},
    }
    whole = simulate(beam_scene([lift, turn], steps=4), tmp_path / "whole", progress=False)
    simulate(beam_scene([lift, turn], steps=2), tmp_path / "split", progress=False)
    resumed = simulate(beam_scene([lift, turn], steps=4), tmp_path / "split", progress=False, resume=True)
    assert [r["step"] for r in resumed.step_records] == [1, 2, 3, 4] and resumed.steps_run == 4
    assert [r["after_step"] for r in resumed.summary["resumes"]] == [2]
    # same code path and inputs on the same machine: equal to round-off of the linear solves
    np.testing.assert_allclose(resumed.x, whole.x, rtol=0, atol=1e-10)


def test_a_damaged_blocked_state_in_the_checkpoint_is_named(tmp_path):
    """Blocked targets of the wrong shape in a checkpoint: an error naming the checkpoint, not a traceback."""
    from idp.errors import SolverError

    lift = {"name": "lift", "select": RIGHT, "motion": {"type": "translate", "velocity": [0, 1.0, 0]}}
    simulate(beam_scene([lift], steps=1), tmp_path / "run", progress=False)
    path = tmp_path / "run" / "checkpoint.npz"
    ck = dict(np.load(path))
    (key,) = [k for k in ck if k.endswith("__kappa_B")]
    pre = key.removesuffix("kappa_B")
    ck[pre + "dirichlet_blocked_vertices"] = np.array([0, 1])
    ck[pre + "dirichlet_blocked_targets"] = np.zeros((3, 3))
    np.savez(path, **ck)
    with pytest.raises(SolverError, match=r"checkpoint .*checkpoint\.npz: blocked_targets has shape \(3, 3\)"):
        simulate(beam_scene([lift], steps=2), tmp_path / "run", progress=False, resume=True)


def test_handle_selects_a_vertex_group_read_from_the_mesh_file(tmp_path):
    import meshio

    from idp.mesh import generate as gen

    m = gen.tet_box(lo=(-0.5, -0.05, -0.05), hi=(0.5, 0.05, 0.05), resolution=(20, 2, 2))
    tip = (m.vertices[:, 0] > 0.49).astype(np.int32)
    path = tmp_path / "beam.vtu"
    meshio.write(path, meshio.Mesh(m.vertices, [("tetra", m.elements)], point_data={"tip": tip}))
    d = {
        "time": {"h": H, "steps": 2},
        "contact": {"dhat": 1e-3},
        "output": {"obj": False, "vtu": False, "png": False},
        "objects": [
            {
                "name": "beam",
                "mesh": str(path),
                "fixed": [LEFT],
                "handles": [
                    {
                        "name": "tip",
                        "select": {"group": "tip"},
                        "motion": {"type": "translate", "velocity": [0, 0.5, 0]},
                    }
                ],
            }
        ],
    }
    built = build_scene(scene_from_dict(d))
    h = built.system.conditions[0].handles[0]
    np.testing.assert_array_equal(np.sort(h.vertices), np.flatnonzero(tip))
    d["objects"][0]["handles"][0]["select"] = {"group": "nose"}
    with pytest.raises(SceneError, match=r"handles\[0\].*no vertex group 'nose' \(it has: tip\)"):
        build_scene(scene_from_dict(d))


def test_generated_solid_as_a_kinematic_obstacle_uses_its_boundary(tmp_path):
    finger = {
        "name": "finger",
        "kind": "obstacle",
        "generate": {"shape": "ellipsoid", "radii": [0.05, 0.1, 0.05], "center": [0.3, 0.2, 0.0], "resolution": 3},
        "motion": {"motion": {"type": "translate", "velocity": [0.0, -1.0, 0.0]}},
    }
    s = beam_scene([], steps=3, extra_objects=[finger])
    built = build_scene(s)
    part = built.system.parts[1]
    assert np.unique(part.surface).size == part.vertex_ids.size  # no interior vertices
    res = simulate(s, tmp_path, progress=False)
    recs = certified(res)
    assert max(r["contacts"] for r in recs) > 0  # it reached the beam and pushed it


def test_incremental_and_exponential_scale_handles():
    """An exponential scale shrinks by the same fraction each step; an incremental handle applies one step of its
    motion to where its vertices are (a blocked handle is not pushed further), and holds after its end."""
    from idp.mesh.selection import Selection
    from idp.stepper.handles import Handle
    from idp.stepper.motions import Scale

    x = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 2.0], [5.0, 5.0, 5.0]])
    rate, dt = np.log(0.9) / 0.04, 0.04
    law = Scale(np.array([rate, 0.0, rate]), 0.0, "exponential")
    np.testing.assert_allclose(law.targets(x[:2], 3 * dt), x[:2] * [0.9**3, 1.0, 0.9**3], rtol=1e-12)
    ids = np.arange(3)
    absolute = Handle("a", ids, Selection(indices=np.array([0, 1])), law, end=3)
    incremental = Handle("i", ids, Selection(indices=np.array([0, 1])), law, end=3, incremental=True)
    blocked = x.copy()  # the vertices did not move at all during the first two steps
    for step in (1, 2, 3):
        t_abs = absolute.targets(step, blocked, dt)
        t_inc = incremental.targets(step, blocked, dt)
    np.testing.assert_allclose(t_abs, x[:2] * [0.9**3, 1.0, 0.9**3], rtol=1e-12)  # ran away from the vertices
    np.testing.assert_allclose(t_inc, x[:2] * [0.9, 1.0, 0.9], rtol=1e-12)  # one step from where they are
    moved = blocked.copy()
    moved[:2] *= 0.5
    np.testing.assert_allclose(incremental.targets(4, moved, dt), moved[:2])  # past the end: held
    np.testing.assert_allclose(incremental.targets(5, blocked, dt), moved[:2])


def test_incremental_is_refused_for_position_motions():
    from idp.scene.conditions_schema import MotionSpec

    with pytest.raises(Exception, match="incremental"):
        MotionSpec(type="fixed", incremental=True)
    with pytest.raises(Exception, match="law"):
        MotionSpec(type="translate", velocity=[0, 1, 0], law="exponential")


def test_handle_selection_with_exclude_takes_the_excluded_vertices_out():
    # the right tenth of the beam minus a ball about its tip corner: the tip face keeps only far vertices
    ball = {"sphere": {"center": [0.5, 0.05, 0.05], "radius": 0.06}}
    select = {**RIGHT, "exclude": ball}
    built = build_scene(beam_scene([{"name": "tip", "select": select}], steps=1))
    x = built.system.x.reshape(-1, 3)
    chosen = built.system.conditions[0].handles[0].vertices
    box = np.flatnonzero(x[:, 0] >= 0.5 - 0.02 - 1e-12)
    near = np.linalg.norm(x - [0.5, 0.05, 0.05], axis=1) <= 0.06
    np.testing.assert_array_equal(np.sort(chosen), box[~near[box]])
    assert 0 < chosen.size < box.size


def test_exclude_vectors_are_checked_against_dim():
    bad = {**RIGHT, "exclude": {"sphere": {"center": [0.5, 0.05], "radius": 0.06}}}
    with pytest.raises(SceneError, match=r"handles\[0\]\.select\.exclude\.sphere\.center"):
        beam_scene([{"name": "tip", "select": bad}], steps=1)


def test_a_decrement_within_tol_that_did_not_end_the_solve_is_explained(tmp_path, caplog):
    """A step stopped by the iteration cap right after an iterate whose decrement was within tol, but whose
    handles were still being pulled (κ_B doubled): the record and the warning say why it did not converge."""
    import logging

    free_run = simulate(tip_into_block(steps=1), tmp_path / "free", progress=False)
    rec = free_run.step_records[0]
    assert rec["converged"] and not rec["dirichlet"]["met"]
    within = [i for i, d in enumerate(rec["decrements"][:-1]) if d <= 1e-2]
    assert within, "no iterate within tol before the last: the scene tests nothing"
    cap = within[0] + 1
    with caplog.at_level(logging.WARNING, logger="idp"):
        capped = simulate(
            tip_into_block(steps=1, solver={"newton_tol": 1e-2, "max_newton_iterations": cap}),
            tmp_path / "capped",
            progress=False,
        )
    rec = capped.step_records[0]
    assert rec["hit_iteration_cap"] and not rec["converged"] and rec["newton_decrement"] <= 1e-2
    assert "step constraint" in rec["decrement_unconfirmed"]
    assert "<= tol 0.01, but the step constraint" in caplog.text and "> tol" not in caplog.text
