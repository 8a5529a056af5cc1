"""The fault-injection switch of the crash-safety tests: inert unless asked, refusing unknown points."""

from __future__ import annotations

import pytest

from idp import _faults


def test_plans_are_parsed_and_unknown_points_refused():
    assert _faults._parse(None) is None and _faults._parse("") is None
    assert _faults._parse("checkpoint:3, newton") == {"checkpoint": 3, "newton": 1}
    with pytest.raises(ValueError, match="unknown point 'nowhere'"):
        _faults._parse("nowhere:1")


def test_without_a_plan_every_point_is_a_no_op(monkeypatch):
    monkeypatch.setattr(_faults, "_PLAN", None)
    for name in _faults.POINTS:
        _faults.kill_point(name)  # still alive


def test_a_point_fires_only_at_its_pass(monkeypatch):
    fired = []
    monkeypatch.setattr(_faults, "_PLAN", {"stats": 2})
    monkeypatch.setattr(_faults, "_PASSES", {})
    monkeypatch.setattr(_faults.os, "kill", lambda pid, sig: fired.append(sig))
    _faults.kill_point("stats")
    _faults.kill_point("newton")
    assert fired == []
    _faults.kill_point("stats")
    assert len(fired) == 1
