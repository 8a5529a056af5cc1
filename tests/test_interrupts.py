"""Deferred interrupts (idp.interrupts): a first signal inside a run waits for a safe point, a second one does not."""

from __future__ import annotations

import pytest

from idp import interrupts


class Marker(KeyboardInterrupt):
    pass


def test_outside_a_run_a_request_raises_at_once():
    with pytest.raises(Marker):
        interrupts.request(Marker())
    assert not interrupts.pending()


def test_inside_a_run_the_first_request_waits_for_the_checkpoint():
    with pytest.raises(Marker), interrupts.deferred():
        interrupts.request(Marker())  # returns: recorded only
        assert interrupts.pending()
        interrupts.checkpoint()
        pytest.fail("checkpoint did not raise the recorded interrupt")
    assert not interrupts.pending()


def test_a_second_request_raises_at_once():
    with pytest.raises(Marker), interrupts.deferred():
        interrupts.request(KeyboardInterrupt())
        interrupts.request(Marker())
    assert not interrupts.pending()


def test_checkpoint_without_a_request_does_nothing_and_nested_blocks_keep_deferring():
    with interrupts.deferred():
        interrupts.checkpoint()
        with interrupts.deferred():
            pass
        interrupts.request(Marker())  # still inside the outer block: recorded
        assert interrupts.pending()
    assert not interrupts.pending()  # the block ended: dropped, the stepping it would have stopped is over


def test_a_signal_during_newton_stops_the_run_at_the_next_iteration_with_exit_130(tmp_path, monkeypatch):
    """A SIGTERM arriving inside Newton's derivatives (numba and ipctk glue) is raised at the next iteration: the
    run ends with exit 130 and its summary, the interrupted step dropped, the finished ones kept."""
    import json

    from idp import cli
    from idp.solver.newton import StepSolver

    calls = {"n": 0}
    derivatives = StepSolver._derivatives

    def signalled(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 8:  # during step 2 or later: the handler runs here, as a real signal could
            cli._on_sigterm(15, None)
            calls["at"] = calls["n"]
        return derivatives(self, *args, **kwargs)

    monkeypatch.setattr(StepSolver, "_derivatives", signalled)
    out = tmp_path / "out"
    code = cli.main(["run", str(cli.demo_scene_path()), "-o", str(out), "--steps", "40", "-q"])
    assert code == cli.EXIT_INTERRUPTED
    assert calls["n"] == calls["at"]  # not one more derivative evaluation after the signal
    summary = json.loads((out / "stats.json").read_text())["summary"]
    assert summary["stopped"].startswith("interrupted during step")
    assert 1 <= summary["steps_run"] < 40
    assert not interrupts.pending()
