"""Animation repair (paper §7.3) as a thin driver over the shared stepper.

:func:`repair_scene` turns a sequence and the authors' settings into an ordinary scene with a ``[repair]``
section (so a repair is also a reproducible scene file); :func:`run_repair` builds it, runs it through
:func:`idp.api.run_built` — the same Newton loop, certificate, statistics and checkpoint as every scene — with
frames written in the input's own form (:mod:`idp.output.sequence`), then writes the sequence report
(:mod:`idp.output.repair_report`). Frames are read and written one at a time; a killed repair resumes from
its last finished frame (``resume=True``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from idp.errors import SceneError
from idp.fs import check_output_dir, is_file, make_output_dir
from idp.scene.repair_schema import REPAIR_DHAT
from idp.scene.schema import Scene

log = logging.getLogger("idp")

#: the authors' mannequin set-up (manifest, repair/): head and neck box, relative to the first frame's bbox
MANNEQUIN_HEAD_BOX = [[-0.1, 0.867, -0.1], [1.1, 1.1, 1.1]]


def parse_frames(text: str) -> tuple[int, int | None]:
    """``"A:B"`` (B exclusive, either may be empty) → (start, stop)."""
    a, sep, b = text.partition(":")
    try:
        start = int(a) if a.strip() else 0
        stop = int(b) if b.strip() else None
    except ValueError:
        raise SceneError(f"--frames {text!r}: expected A:B with integers (B exclusive), e.g. 0:121") from None
    if not sep:
        raise SceneError(f"--frames {text!r}: expected A:B (B exclusive), e.g. 10:50")
    return start, stop


def parse_selection(text: str) -> dict[str, Any]:
    """A ``--fixed`` selection: ``box:x0,y0,z0,x1,y1,z1`` (absolute corners), ``relbox:...`` (relative to the
    first frame's bounding box, 0 = min, 1 = max) or ``indices:i,j,k`` / ``indices:FILE`` (whitespace or
    comma separated, 0-based)."""
    kind, sep, rest = text.partition(":")
    kind = kind.strip().lower()
    if not sep or kind not in ("box", "relbox", "indices"):
        raise SceneError(f"--fixed {text!r}: expected box:x0,y0,z0,x1,y1,z1, relbox:... or indices:i,j,k|FILE")
    if kind == "indices":
        src = Path(rest)
        body = rest
        if is_file(src):
            try:
                body = src.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:  # a binary or unreadable file
                raise SceneError(f"--fixed {text!r}: cannot read the index file {src}: {exc}") from None
        try:
            idx = [int(t) for t in body.replace(",", " ").split()]
        except ValueError:
            raise SceneError(f"--fixed {text!r}: indices must be integers") from None
        if not idx:
            raise SceneError(f"--fixed {text!r}: no index given")
        return {"indices": idx}
    try:
        vals = [float(t) for t in rest.split(",")]
    except ValueError:
        raise SceneError(f"--fixed {text!r}: box corners must be numbers") from None
    if len(vals) != 6:
        raise SceneError(f"--fixed {text!r}: a box needs 6 numbers x0,y0,z0,x1,y1,z1 (got {len(vals)})")
    return {"box": [vals[:3], vals[3:]], "relative": kind == "relbox"}


def repair_scene(
    sequence: str | Path,
    *,
    dhat: float = REPAIR_DHAT,
    prescribed: list[dict[str, Any]] | None = None,
    start: int = 0,
    stop: int | None = None,
    first_frame: str = "error",
    output: str = "same",
    usd_prim: str | None = None,
    youngs_modulus: float = 100.0,
    poisson_ratio: float = 0.4,
    thickness: float = 0.01,
    bending: float = 1.0,
    density: float = 1000.0,
    h: float = 0.04**2,
    newton_tol: float | None = None,
    kappa_b: float | None = None,
    prescribed_contact: str = "follow_input",
    name: str | None = None,
) -> Scene:
    """A validated repair scene for ``sequence`` (see :class:`idp.scene.repair_schema.RepairConfig`); the
    defaults are the authors' mannequin set-up (d̂ = 1e-2, E = 100, thickness 0.01, bending 1, dt = 0.04).
    ``kappa_b``: the initial §4.3 penalty κ_B that pulls prescribed vertices onto the input when their straight
    move collides (default the scene default, 1e4; docs/animation-repair.md measures when a large start pays).
    ``prescribed_contact``: ``follow_input`` (pairs among prescribed vertices left out of contact: they follow the
    input exactly) or ``guarded`` (see :class:`idp.scene.repair_schema.RepairConfig`)."""
    doc: dict[str, Any] = {
        "name": name or Path(str(sequence)).stem.replace("*", "") or "repair",
        "dim": 3,
        "time": {"h": float(h)},
        "contact": {"dhat": float(dhat)},
        "solver": {} if newton_tol is None else {"newton_tol": float(newton_tol)},
        "repair": {
            "input": str(sequence),
            "start": int(start),
            "first_frame": first_frame,
            "output": output,
            "prescribed": list(prescribed or []),
            "prescribed_contact": prescribed_contact,
        },
        "objects": [
            {
                "name": "surface",
                "kind": "shell",
                "mesh": str(sequence),
                "frame": int(start),
                "shell": {
                    "youngs_modulus": float(youngs_modulus),
                    "poisson_ratio": float(poisson_ratio),
                    "thickness": float(thickness),
                    "bending": float(bending),
                    "density": float(density),
                },
            }
        ],
    }
    if kappa_b is not None:
        doc["dirichlet"] = {"kappa_initial": float(kappa_b)}
    if stop is not None:
        doc["repair"]["stop"] = int(stop)
    if usd_prim is not None:
        doc["repair"]["usd_prim"] = usd_prim
    from idp.scene.load import scene_from_dict

    return scene_from_dict(doc)


def _output_path(out: Path, seq: Any, fmt: str) -> Path:
    """Where the repaired sequence goes inside ``out``: ``frames/`` (OBJ), ``sequence/`` (PVD + VTU),
    ``<input stem>.npz`` or ``<input stem>.usd[a|c]``."""
    stem = Path(str(seq.path)).stem.replace("*", "") or "sequence"
    if fmt == "obj":
        return out / "frames"
    if fmt == "pvd":
        return out / "sequence"
    if fmt == "npz":
        return out / f"{stem}.npz"
    suffix = Path(str(seq.path)).suffix if seq.format == "usd" else ".usdc"
    return out / f"{stem}{suffix}"


class RepairFrameWriter:
    """The run loop's frame writer for a repair: step s → input frame ``frames[s]``, written in the sequence's
    form; a frame equal to its input bit for bit is marked unchanged (OBJ/VTU inputs are then copied byte for
    byte). The sequence is finished (PVD index, npz/USD assembled) only once every frame is on disk, so an
    interrupted repair leaves its finished frames resumable and nothing that looks like a whole sequence."""

    def __init__(self, writer: Any, condition: Any) -> None:
        self.writer = writer
        self.condition = condition
        self.last_step = len(condition.frames) - 1
        self.complete = False

    def write(self, step: int, x: np.ndarray, time: float | None = None, cell_data: Any = None) -> None:
        c = self.condition
        k = c.frame_index(step)
        v = c.output(x)
        f = c.input if c.input is not None and c.frame_index(c.step) == k else c.sequence.frame(k)
        unchanged = bool(np.array_equal(v, f))
        dtype = np.dtype(getattr(self.writer, "coordinate_dtype", np.float64))
        if not unchanged and dtype != np.float64:
            self._check_rounded(k, v, dtype)
        self.writer.write(k, v, unchanged=unchanged)
        self.complete = step == self.last_step

    def _check_rounded(self, k: int, v: np.ndarray, dtype: np.dtype) -> None:
        """A format that stores fewer digits (USD's float32 points) writes a rounded frame: certify that one too
        (rounding moves a vertex by ~1e-7 of its coordinates, far below d̂, but the certificate is the rule)."""
        from idp.contact.intersections import intersecting_pair_keys
        from idp.errors import CertificateError

        rounded = v.astype(dtype).astype(np.float64)
        c = self.condition
        X = np.zeros((int(c.vertex_ids.max()) + 1, 3))
        X[c.vertex_ids] = rounded
        new = intersecting_pair_keys(X, c.faces) - c.preserved
        if new:
            raise CertificateError(
                f"frame {k}: rounding to {dtype} for {self.writer.out} makes {len(new)} surface pair(s) cross; "
                "write another form (--format npz/obj/pvd keep float64)"
            )

    def close(self) -> None:
        if self.complete:
            self.writer.close()


def run_repair(
    scene: Scene,
    out_dir: str | Path,
    *,
    progress: bool = True,
    resume: bool = False,
    steps: int | None = None,
    force_resume: bool = False,
):
    """Repair the scene's sequence into ``out_dir``: the repaired sequence, stats.json, report.json/.md and
    pictures; returns the RunResult (``summary["repair"]`` holds the sequence figures)."""
    if scene.repair is None:
        raise SceneError("repair: the scene has no [repair] section")
    from idp.api import run_built
    from idp.output.sequence import sequence_writer
    from idp.scene.build import build_scene
    from idp.stepper.repair_frames import RepairFrames

    out = check_output_dir(out_dir)
    built = build_scene(scene, steps=steps)  # bad input (frames, selections, crossings) fails before any write
    cond = next(c for c in built.system.conditions if isinstance(c, RepairFrames))
    seq = cond.sequence
    fmt = seq.format if scene.repair.output == "same" else scene.repair.output
    seq_out = _output_path(out, seq, fmt)
    make_output_dir(out)
    frames = cond.frames[: built.run.steps + 1]  # a step cap (bench, --steps) repairs the first frames only
    writer = RepairFrameWriter(sequence_writer(seq_out, seq.faces, like=seq, format=fmt, frames=frames), cond)
    writer.last_step = len(frames) - 1
    if resume:  # an earlier run may have finished its (shorter) sequence: extend it
        writer.writer.recover_finished(list(frames))
    result = run_built(scene, built, out, progress=progress, resume=resume, force_resume=force_resume, writer=writer)
    from idp.mesh.sequence import open_sequence
    from idp.output.repair_report import write_repair_report

    if fmt == "pvd":
        seq_out = next(seq_out.glob("*.pvd"))
    repaired = open_sequence(seq_out)
    position = {k: i for i, k in enumerate(cond.frames)}
    from idp.output.stats import load_stats

    report = write_repair_report(
        out,
        load_stats(out / "stats.json")["steps"],  # with the start state's record
        result.summary,
        faces=seq.faces,
        read_input=seq.frame,
        read_output=lambda k: repaired.frame(position[k]),
        title=scene.name,
    )
    result.summary["repair"] = report.get("sequence", {})
    result.summary["repaired_sequence"] = str(seq_out)
    return result
