"""Run the authors' reference code beside idp, on the same machine and in turn (``idp bench --with-reference``).

A speed-up is only meaningful when both codes run on the same machine under the same load, so the suite runs
idp and the prebuilt reference (``../shared/reference``, the authors' unchanged C++ code behind a thin
``run.sh`` wrapper) alternately, scene by scene, and reports medians and per-run ratios. This module knows

- which suite scene corresponds to which reference script and arguments (``REFERENCE_CASES``);
- where the reference lives (``find_reference``) and how to run it (``run_reference``);
- how to read its output: the ``REF_STEP`` / ``REF`` lines of ``run.sh`` (``parse_ref_output``) and the timing
  tree the authors' code prints into its log (``parse_timing_tree``, ``reference_split``).

Nothing of the reference is copied: it is run as a separate process and only its printed figures are read.
"""

from __future__ import annotations

import os
import re
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from idp.bench.reference_blas import choose_reference_blas


@dataclass(frozen=True)
class ReferenceCase:
    """The reference run that corresponds to one suite scene: ``run.sh SCRIPT ARGS...``."""

    script: str
    args: tuple[str, ...]
    note: str = ""

    @property
    def command(self) -> str:
        return " ".join(("run.sh", self.script, *self.args))


REFERENCE_CASES: dict[str, ReferenceCase] = {
    "bunny_700": ReferenceCase("bunny", ("0",)),
    "bunny_1922": ReferenceCase("bunny", ("1",)),
    "bunny_3376": ReferenceCase("bunny", ("2",)),
    "bunny_4815": ReferenceCase("bunny", ("3",)),
    "bunny_7448": ReferenceCase("bunny", ("4",)),
    "bunnyx30_13K": ReferenceCase("bunny", ("5",)),
    # the script's own PNTol 1e-2 does not converge its first step in 560 Newton iterations; 1 is the bunnies'
    "tube_in_tube": ReferenceCase("tube", ("1",), "PNTol 1 (the script's default 1e-2 stalls in step 1)"),
    "hourglass_bunny": ReferenceCase("hourglass", ("0", "20", "30")),
    "hourglass_octocat": ReferenceCase("hourglass", ("3", "20", "30")),
}
"""Suite scene -> reference run. Scenes not listed have no counterpart in the authors' §6 scripts (flows, repair,
min-max, handles); the report says so (flows are compared by ``bench/reference_flow.py``, which drives the
authors' shell flow). The authors' hourglass case 2 (octocat6K) is left out on purpose: it places
an unscaled octocat (volume ≈ 24,000) in a cage of volume ≈ 0.05, crossing it from the start, which idp refuses."""


def find_reference(data_dir: Path | None = None) -> Path | None:
    """The prebuilt reference folder: ``$IDP_REFERENCE``, else ``reference/`` beside the paper's data folder,
    else ``../shared/reference`` from the working directory; None when none has a ``run.sh``."""
    candidates: list[Path] = []
    if os.environ.get("IDP_REFERENCE"):
        candidates.append(Path(os.environ["IDP_REFERENCE"]))
    if data_dir is not None:
        candidates.append(Path(data_dir).resolve().parent / "reference")
    candidates.append(Path.cwd().parent / "shared" / "reference")
    for c in candidates:
        if (c / "run.sh").is_file():
            return c.resolve()
    return None


_KEY_VALUE = re.compile(r"(\w+)=(\S+)")


def _numbers(line: str) -> dict:
    out: dict = {}
    for key, value in _KEY_VALUE.findall(line):
        try:
            out[key] = int(value)
        except ValueError:
            try:
                out[key] = float(value)
            except ValueError:
                out[key] = value
    return out


def parse_ref_output(stdout: str) -> dict:
    """The figures of one ``run.sh`` run: the last ``REF`` line's fields plus the per-step records.

    Raises ValueError when the output holds no ``REF`` line (the run failed or was cut short)."""
    steps, final = [], None
    for line in stdout.splitlines():
        if line.startswith("REF_STEP "):
            steps.append(_numbers(line))
        elif line.startswith("REF "):
            final = _numbers(line)
    if final is None:
        raise ValueError("the reference printed no final 'REF ...' line")
    final["per_step"] = steps
    return final


_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_DURATION = r"(?:\d+h )?(?:\d+m )?[0-9.eE+-]+s"  # the authors' timers print e.g. "0.04s", "1m 45.52s", "1h 2m 3.1s"
_NODE = re.compile(rf"^([┃┏]+) (.+?) : ({_DURATION}) \([^)]*\)\s+({_DURATION})")


def _seconds(text: str) -> float:
    total = 0.0
    for part in text.split():
        unit = {"h": 3600.0, "m": 60.0, "s": 1.0}[part[-1]]
        total += float(part[:-1]) * unit
    return total


def parse_timing_tree(log: str) -> list[tuple[int, str, float]]:
    """The last cumulative timing tree the authors' code prints (the block headed ``Global``):
    ``(depth, name, seconds summed over the run)`` in print order, depth 1 for ``Global``."""
    lines = _ANSI.sub("", log).splitlines()
    start = max((i for i, ln in enumerate(lines) if ln.startswith("┏ Global ")), default=None)
    if start is None:
        return []
    nodes = []
    for ln in lines[start:]:
        m = _NODE.match(ln)
        if m:
            prefix = m.group(1)  # "┏" opens a block at its own depth; "┃" lines are children of the open block
            depth = len(prefix) if prefix.endswith("┏") else len(prefix) + 1
            nodes.append((depth, m.group(2).strip(), _seconds(m.group(4))))
        elif ln.strip() and not ln.startswith(("┃", "┗", "┏")):
            break
    return nodes


# the reference's timers grouped like idp's per-iteration split (names as the authors' code prints them)
REFERENCE_GROUPS: dict[str, tuple[str, ...]] = {
    "assembly": (
        "Compute_IncPotential_Gradient",
        "Compute_IncPotential_Hessian",
        "constructCSRMatrixFromTriplet",
        "projectDBC",
    ),
    "linear_solve": ("linearSolve",),
    "ccd": ("Compute_Intersection_Free_StepSize",),
    "line_search": ("Compute_IncPotential",),
    "contact_build": ("Compute_Constraint_Set", "Find Object Boundary"),
}


def reference_split(tree: list[tuple[int, str, float]], newton_iterations: int) -> dict[str, float]:
    """Seconds per Newton iteration in idp's categories, from the reference's timing tree. ``other`` is the
    solver node's remainder (inversion-free step size, x̃, bookkeeping); ``outside_solver`` is everything the
    ``Global`` timer saw outside it (frame writes)."""
    if not tree or newton_iterations <= 0:
        return {}
    # Global (depth 1) > the time stepper's node, the largest at depth 2 > its children (depth 3)
    top = [i for i, (depth, _, _) in enumerate(tree) if depth == 2]
    if not top:
        return {}
    solver = max(top, key=lambda i: tree[i][2])
    solver_total = tree[solver][2]
    children: dict[str, float] = {}
    for depth, name, sec in tree[solver + 1 :]:
        if depth <= 2:
            break
        if depth == 3:
            children[name] = children.get(name, 0.0) + sec
    global_total = tree[0][2]
    split = {group: sum(children.get(n, 0.0) for n in names) for group, names in REFERENCE_GROUPS.items()}
    split["other"] = max(solver_total - sum(split.values()), 0.0)
    split["outside_solver"] = max(global_total - solver_total, 0.0)
    return {k: v / newton_iterations for k, v in split.items()}


def run_measured(cmd: list[str], env: dict[str, str], log: Path) -> tuple[float, float, int]:
    """Run ``cmd`` with its output in ``log``; (process wall s, peak RSS MB of the child, exit code)."""
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
    return time.perf_counter() - t0, usage.ru_maxrss / 1024.0, os.waitstatus_to_exitcode(status)


def run_reference(
    reference: Path,
    case: ReferenceCase,
    work_dir: Path,
    data_dir: Path | None,
    timeout: float | None = None,
    blas: str = "auto",
) -> dict:
    """Run one reference case in ``work_dir`` (kept: ``run.log``, the authors' verbose log; the frames they
    write are removed) and return its figures, its timing tree and the wall time seen from here. ``blas``: which
    OpenBLAS kernels it runs on (:func:`idp.bench.reference_blas.choose_reference_blas`; recorded as ``blas``)."""
    if work_dir.exists():
        shutil.rmtree(work_dir)
    work_dir.mkdir(parents=True)
    env = dict(os.environ, PYTHON=sys.executable, REF_RUN_DIR=str(work_dir))
    if data_dir is not None:
        env["IDP_DATA"] = str(data_dir)
    env, blas_choice = choose_reference_blas(env, blas)
    t0 = time.perf_counter()
    proc = subprocess.run(
        ["bash", str(reference / "run.sh"), case.script, *case.args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    outer_wall = time.perf_counter() - t0
    (work_dir / "stdout.txt").write_text(proc.stdout)
    if proc.returncode != 0:
        tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-6:])
        raise RuntimeError(f"reference {case.command} failed (exit {proc.returncode}):\n{tail}")
    result = parse_ref_output(proc.stdout)
    log = work_dir / "run.log"
    tree = parse_timing_tree(log.read_text(errors="replace")) if log.is_file() else []
    for leftover in ("Projects", "Python", "build", "final_tets.vtk"):  # frames and links: not needed afterwards
        p = work_dir / leftover
        if p.is_symlink() or p.is_file():
            p.unlink()
        elif p.is_dir():
            shutil.rmtree(p)
    result["outer_wall"] = outer_wall
    result["blas"] = blas_choice
    result["timing_tree"] = [list(node) for node in tree]
    result["per_iteration_split"] = reference_split(tree, int(result.get("newton_its", 0)))
    return result


def compare(idp_runs: list[dict], ref_runs: list[dict], cage_volume: float | None) -> dict:
    """Medians and per-run ratios of alternating idp / reference runs of one scene.

    ``speedup_per_run[i]`` = reference wall / idp wall of the i-th pair; ``speedup`` = ratio of the medians."""
    idp_walls = [r["wall_process"] for r in idp_runs]
    ref_walls = [float(r["wall_s"]) for r in ref_runs]
    per_run = [rw / iw for iw, rw in zip(idp_walls, ref_walls, strict=False)]
    ref = ref_runs[-1]
    ref_fill = float(ref["tet_volume"]) / cage_volume if cage_volume and "tet_volume" in ref else None
    return {
        "runs": min(len(idp_walls), len(ref_walls)),
        "idp_wall_median": statistics.median(idp_walls),
        "reference_wall_median": statistics.median(ref_walls),
        "idp_walls": idp_walls,
        "reference_walls": ref_walls,
        "speedup": statistics.median(ref_walls) / statistics.median(idp_walls),
        "speedup_per_run": per_run,
        "speedup_spread": [min(per_run), max(per_run)] if per_run else None,
        "idp_newton_iterations": idp_runs[-1]["newton_iterations"],
        "reference_newton_iterations": int(ref["newton_its"]),
        "idp_fill": idp_runs[-1]["fill_final"],
        "reference_fill": ref_fill,
        "reference_steps": int(ref.get("steps", 0)),
        "idp_peak_rss_mb": max(r["peak_rss_mb"] for r in idp_runs),
        "reference_peak_rss_mb": max(float(r["peak_rss_mb"]) for r in ref_runs),
        "reference_split": ref.get("per_iteration_split", {}),
        "reference_blas": ref.get("blas"),
    }
