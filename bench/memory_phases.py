"""Where a run reaches its peak memory: every rise of VmHWM attributed to the phase running then (not a test).

Wraps the run's phases (scene build, assembly parts, CHOLMOD calls, line search, CCD, certificate, frame writes);
on entry and exit of each it reads VmHWM from /proc/self/status and charges any rise to the innermost phase running.
VmHWM catches peaks between the reads, so nothing is sampled. A bench scene (``idp bench`` names) runs from the
start, or from a copy of an interrupted or finished run's folder (``--resume FOLDER``, which holds its checkpoint)
for the late, contact-heavy steps only. Linux only. Used for docs/benchmarks.md, "Memory (issue 16)":

    export IDP_DATA=../shared/data PYTHONPATH=.
    .venv/bin/python -c "from idp.bench.suite import scene_table; from idp.api import simulate;
    simulate(scene_table()['bunnyx30_13K'][0](), 'ck50', steps=50, progress=False)"     # once: about 4 minutes
    .venv/bin/python bench/memory_phases.py bunnyx30_13K --resume ck50 --steps 60       # 10 steps: 12 s
"""

from __future__ import annotations

import argparse
import functools
import shutil
import tempfile
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _hwm_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("VmHWM not in /proc/self/status")


class _Attribution:
    """Rises of VmHWM per phase (MB) and the high-water mark at each phase's last rise."""

    def __init__(self) -> None:
        self.rises: dict[str, float] = defaultdict(float)
        self.last_rise: dict[str, float] = {}
        self.stack = ["start-up"]
        self.hwm = _hwm_mb()

    def note(self) -> None:
        h = _hwm_mb()
        if h > self.hwm:
            self.rises[self.stack[-1]] += h - self.hwm
            self.last_rise[self.stack[-1]] = h
            self.hwm = h

    def wrap(self, owner: Any, name: str, label: str) -> None:
        """Replace ``owner.name`` (a function or method) by one that notes VmHWM on entry and exit."""
        f: Callable[..., Any] = getattr(owner, name)

        @functools.wraps(f)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            self.note()
            self.stack.append(label)
            try:
                return f(*args, **kwargs)
            finally:
                self.note()
                self.stack.pop()

        setattr(owner, name, wrapped)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="a scene of `idp bench` (e.g. bunnyx30_13K)")
    ap.add_argument("--resume", type=Path, help="a run folder with a checkpoint (copied, then resumed)")
    ap.add_argument("--steps", type=int, help="run up to this step")
    args = ap.parse_args()

    import idp.api
    import idp.contact.certificate as certificate
    import idp.contact.model as contact_model
    import idp.output.frames as frames
    import idp.solver.cholmod_cvxopt as cholmod_backend
    import idp.solver.contact_pattern as contact_pattern
    import idp.solver.newton as newton
    from idp.bench.suite import scene_table

    a = _Attribution()
    a.wrap(idp.api, "build_scene", "build scene")
    a.wrap(newton.StepSolver, "_derivatives", "assembly: elastic + gradient")
    a.wrap(contact_model.HessianBlockStream, "blocks", "assembly: barrier Hessian blocks (a range at a time)")
    a.wrap(contact_pattern.GrowingBlockPattern, "_scatter_listing", "assembly: contact scatter")
    a.wrap(contact_pattern.GrowingBlockPattern, "add_block_stream", "assembly: contact fold / growth")
    a.wrap(contact_pattern.GrowingBlockPattern, "_set_extra", "assembly: contact pattern growth")
    a.wrap(newton.StepSolver, "_direction", "linear solve: other")
    a.wrap(newton.StepSolver, "_exact_direction", "exact direction (CG)")
    a.wrap(cholmod_backend.CholmodSolver, "_load_changed_pattern", "linear: new pattern's index maps")
    a.wrap(cholmod_backend.CholmodSolver, "_analyse", "linear: ordering + symbolic")
    a.wrap(cholmod_backend.cholmod, "numeric", "linear: CHOLMOD numeric")
    a.wrap(cholmod_backend.cholmod, "solve", "linear: CHOLMOD solve")
    a.wrap(newton.StepSolver, "_filtered_step", "line search")
    a.wrap(contact_model.ContactModel, "sweep_candidates", "broad phase")
    a.wrap(contact_model.ContactModel, "max_collision_free_step", "CCD")
    a.wrap(newton.StepSolver, "_contact_eval", "collision sets")
    a.wrap(certificate.Certifier, "check", "certificate")
    a.wrap(frames.FrameWriter, "write", "frame write")

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / args.scene
        if args.resume is not None:
            shutil.copytree(args.resume, out)
        scene = scene_table()[args.scene][0]()
        res = idp.api.simulate(scene, out, steps=args.steps, progress=False, resume=args.resume is not None)
        a.stack.append("end")
        a.note()
    print(f"{args.scene}: {res.summary['newton_iterations']} Newton iterations, fill {res.summary['fill_fraction']}")
    print(f"{'phase':40s} {'VmHWM rise':>11s} {'VmHWM at its last rise':>23s}")
    for label in sorted(a.rises, key=lambda k: a.last_rise[k]):
        print(f"{label:40s} {a.rises[label]:8.1f} MB {a.last_rise[label]:20.1f} MB")


if __name__ == "__main__":
    main()
