"""Fault injection for the crash-safety tests: kill this process at a named point of a run.

``IDP_KILL_AT="checkpoint:3"`` makes the third pass through the point ``checkpoint`` send this process SIGKILL
(``name:count`` pairs may be joined by commas; count defaults to 1). The points sit where an interruption is
most harmful — inside a Newton step, between a frame's temporary file and its rename, between a frame's OBJ and
its VTU, inside the checkpoint and stats writes — so the tests can prove that a run killed there resumes to the
very bytes of an uninterrupted run. Without the variable (every normal run) :func:`kill_point` only looks up
one module-level ``None``.
"""

from __future__ import annotations

import os
import signal

POINTS = (
    "newton",  # after an accepted Newton iterate, before the next (idp.solver.newton)
    "frame_tmp",  # a frame file written to its temporary name, not yet renamed (idp.output.frames)
    "frame_between",  # a frame's OBJ in place, its VTU not yet written
    "pvd",  # the PVD index's temporary file written, not yet renamed
    "checkpoint",  # the checkpoint's temporary file written, not yet renamed (idp.stepper.run)
    "stats",  # stats.json's temporary file written, not yet renamed (idp.output.stats)
    "stage",  # a stage finished, its done marker not yet written (idp.applications.modeling)
)


def _parse(text: str | None) -> dict[str, int] | None:
    if not text:
        return None
    plan: dict[str, int] = {}
    for item in text.split(","):
        name, _, count = item.strip().partition(":")
        if name not in POINTS:
            raise ValueError(f"IDP_KILL_AT: unknown point {name!r} (known: {', '.join(POINTS)})")
        plan[name] = int(count) if count else 1
    return plan


_PLAN = _parse(os.environ.get("IDP_KILL_AT"))
_PASSES: dict[str, int] = {}


def kill_point(name: str) -> None:
    """SIGKILL this process if ``IDP_KILL_AT`` asks for it at this pass through ``name``; otherwise nothing."""
    if _PLAN is None or name not in _PLAN:
        return
    _PASSES[name] = _PASSES.get(name, 0) + 1
    if _PASSES[name] == _PLAN[name]:
        os.kill(os.getpid(), signal.SIGKILL)
