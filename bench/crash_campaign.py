"""Crash campaign: kill a run at every pass through every fault point, resume it, compare with an uninterrupted run.

For each point of :mod:`idp._faults` (inside Newton, between a frame's temporary file and its rename, between a
frame's OBJ and VTU, PVD, checkpoint, stats) and each pass 1..N through it, a fresh ``idp run`` of the scene is
killed there with SIGKILL, checked (every frame file on disk is the finished frame), resumed with ``--resume`` and
compared byte for byte with the uninterrupted run (frames, PVD, picture; stats.json apart from wall times).
Writes ``OUT/crash_campaign.json`` and ``.md``.

    .venv/bin/python bench/crash_campaign.py -o runs/crash            # the demo scene, 8 steps
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from idp._faults import POINTS
from idp.cli import demo_scene_path

TIMING = {"wall_time", "timings", "linear_solver", "resumes", "memory_estimate"}


def _strip(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in TIMING}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _outputs(out: Path) -> dict[str, bytes]:
    files = [*out.glob("obj/*.obj"), *out.glob("vtu/*.vtu"), out / "frames.pvd", out / "frames.png"]
    return {str(f.relative_to(out)): f.read_bytes() for f in files if f.is_file()}


def _stats(out: Path) -> Any:
    s = json.loads((out / "stats.json").read_text())
    s["meta"].pop("resolved_scene", None)
    return _strip(s)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="runs/crash")
    ap.add_argument("--scene", default=str(demo_scene_path()))
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--max-passes", type=int, default=40, help="at most this many passes per point")
    args = ap.parse_args()
    root = Path(args.output)
    root.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k != "IDP_KILL_AT"}

    def run(out: Path, *extra: str, kill: str | None = None) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "idp", "run", args.scene, "-o", str(out), "--steps", str(args.steps), "-q"]
        e = dict(env, IDP_KILL_AT=kill) if kill else env
        return subprocess.run([*cmd, *extra], env=e, capture_output=True, text=True)

    t0 = time.perf_counter()
    ref = root / "uninterrupted"
    assert run(ref).returncode == 0
    ref_out, ref_stats = _outputs(ref), _stats(ref)
    rows: list[dict[str, Any]] = []
    for point in (p for p in POINTS if p != "stage"):
        for n in range(1, args.max_passes + 1):
            out = root / f"{point}_{n}"
            killed = run(out, kill=f"{point}:{n}")
            if killed.returncode != -signal.SIGKILL:  # the run had fewer passes through this point
                break
            torn = [k for k, v in _outputs(out).items() if k.startswith(("obj/", "vtu/")) and v != ref_out.get(k)]
            resumed = run(out, "--resume")
            outputs = _outputs(out)
            same = resumed.returncode == 0 and outputs == ref_out and _stats(out) == ref_stats
            rows.append(
                {"point": point, "pass": n, "torn_frames": torn, "resumed_rc": resumed.returncode, "same": same}
            )
            print(f"{point}:{n} {'same bytes' if same else 'DIFFERENT'}", flush=True)
    summary = {
        "scene": args.scene,
        "steps": args.steps,
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs",
        "kills": len(rows),
        "resumed_to_same_bytes": sum(r["same"] for r in rows),
        "frames_torn_after_kill": sum(len(r["torn_frames"]) for r in rows),
        "per_point": {p: sum(r["point"] == p for r in rows) for p in POINTS if p != "stage"},
        "wall_time_s": time.perf_counter() - t0,
        "rows": rows,
    }
    (root / "crash_campaign.json").write_text(json.dumps(summary, indent=2))
    lines = ["| point | kills | resumed to the same bytes |", "|---|---|---|"]
    for p, k in summary["per_point"].items():
        lines.append(f"| {p} | {k} | {sum(r['same'] for r in rows if r['point'] == p)} |")
    lines.append(f"| **all** | **{summary['kills']}** | **{summary['resumed_to_same_bytes']}** |")
    (root / "crash_campaign.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"torn frames after a kill: {summary['frames_torn_after_kill']}; {summary['wall_time_s']:.0f} s")
    return 0 if summary["kills"] == summary["resumed_to_same_bytes"] else 1


if __name__ == "__main__":
    sys.exit(main())
