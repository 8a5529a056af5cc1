"""Per-sequence report of ``idp repair`` (animation repair, paper §7.3).

:func:`write_repair_report` turns the per-step records of ``stats.json`` (each repair step carries a
``"repair"`` sub-dict, see :meth:`idp.stepper.repair_frames.RepairFrames.report`) into

* ``report.json``: one row per repaired frame and the sequence's figures;
* ``report.md``: the same as Markdown tables;
* ``deviation.png``: deviation and new crossing pairs against the frame number;
* ``worst_frame.png``: the frame with the largest deviation, input and repaired side by side (plus a zoom on the
  changed region), coloured by the per-vertex deviation |output − input|.

Pictures are drawn headless (matplotlib Agg through :class:`FigureCanvasAgg`, as :mod:`idp.output.render`); a
failure to draw one is logged and never loses the JSON and Markdown.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from idp.output.render import _DENSE, _normals
from idp.output.stats import to_jsonable

log = logging.getLogger("idp")

_GREY = np.array([0.74, 0.74, 0.76])  # unchanged faces
_CMAP = "plasma"
_ZOOM_FRACTION = 0.1  # the zoom panel shows the vertices deviating by more than this fraction of the maximum


# ----------------------------------------------------------------------------------------------------------- rows


def _select(records: list[dict]) -> list[dict]:
    """The records that make the per-frame table, ordered by step: the regular (solved) records, for a step
    recorded twice (a resumed run that redid it) the last one, and the initial records (the start state, and
    the states resumed runs started from) only where no regular record of their step exists, the first of them
    where several share a step."""
    regular: dict[int, dict] = {}
    initial: list[dict] = []
    for rec in records:
        if not isinstance(rec.get("repair"), dict):
            continue
        if rec.get("initial"):
            initial.append(rec)
        else:
            regular[int(rec.get("step", 0))] = rec
    chosen: dict[int, dict] = dict(regular)
    for rec in initial:
        chosen.setdefault(int(rec.get("step", 0)), rec)
    return [chosen[s] for s in sorted(chosen)]


def _num(v: Any) -> float | None:
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f


def _row(rec: dict) -> dict[str, Any]:
    r = rec["repair"]
    cert = rec.get("certificate")
    return {
        "frame": int(r.get("frame", rec.get("step", 0))),
        "step": int(rec.get("step", 0)),
        "initial": bool(rec.get("initial", False)),
        "unchanged": bool(r.get("unchanged", False)),
        "max_deviation": float(r.get("max_deviation", 0.0)),
        "mean_deviation": float(r.get("mean_deviation", 0.0)),
        "max_coordinate_deviation": float(r.get("max_coordinate_deviation", 0.0)),
        "max_deviation_relative": _num(r.get("max_deviation_relative")),
        "changed_vertices": int(r.get("changed_vertices", 0)),
        "input_crossing_pairs": int(r.get("input_crossing_pairs", 0)),
        "input_crossing_pairs_not_preserved": int(r.get("input_crossing_pairs_not_preserved", 0)),
        "output_crossing_pairs": int(r.get("output_crossing_pairs", 0)),
        "output_crossing_pairs_not_preserved": int(r.get("output_crossing_pairs_not_preserved", 0)),
        "output_crossing_pairs_prescribed": int(r.get("output_crossing_pairs_prescribed", 0)),
        "newton_iterations": int(rec.get("newton_iterations", 0) or 0),
        "wall_time": float(rec.get("wall_time", 0.0) or 0.0),
        "certified": bool(cert.get("ok", False)) if isinstance(cert, dict) else None,
    }


def _sequence(rows: list[dict], summary: dict) -> dict[str, Any]:
    """The sequence's figures. Iterations and per-step wall time are summed over the repaired frames (the start
    state is not solved); ``wall_time`` is the run's (``summary``), which includes setup and output."""
    solved = [r for r in rows if not r["initial"]]
    worst = max(rows, key=lambda r: r["max_deviation"], default=None)
    its = sum(r["newton_iterations"] for r in solved)
    step_time = sum(r["wall_time"] for r in solved)
    wall = _num(summary.get("wall_time"))
    certified = summary.get("all_certified")
    if certified is None:
        certified = all(r["certified"] is not False for r in rows)
    return {
        "frames": len(rows),
        "repaired_frames": len(solved),
        "unchanged_frames": sum(r["unchanged"] for r in rows),
        "changed_frames": sum(not r["unchanged"] for r in rows),
        "frames_with_input_crossings": sum(r["input_crossing_pairs_not_preserved"] > 0 for r in rows),
        "frames_with_output_crossings": sum(r["output_crossing_pairs_not_preserved"] > 0 for r in rows),
        "frames_with_output_crossings_outside_prescribed": sum(
            r["output_crossing_pairs_not_preserved"] > r["output_crossing_pairs_prescribed"] for r in rows
        ),
        "max_deviation": worst["max_deviation"] if worst else 0.0,
        "max_deviation_frame": worst["frame"] if worst and worst["max_deviation"] > 0 else None,
        "max_deviation_relative": worst["max_deviation_relative"] if worst else None,
        "max_coordinate_deviation": max((r["max_coordinate_deviation"] for r in rows), default=0.0),
        "mean_deviation": float(np.mean([r["mean_deviation"] for r in rows])) if rows else 0.0,
        "newton_iterations": its,
        "mean_newton_iterations_per_frame": its / len(solved) if solved else 0.0,
        "wall_time": wall if wall is not None else step_time,
        "step_wall_time": step_time,
        "mean_seconds_per_frame": step_time / len(solved) if solved else 0.0,
        "all_certified": bool(certified),
        "uncertified_frames": int(summary.get("uncertified_frames", sum(r["certified"] is False for r in rows))),
    }


# ------------------------------------------------------------------------------------------------------ text files


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _g(v: float | None, digits: int = 3) -> str:
    return "–" if v is None else f"{v:.{digits}g}"


def _markdown(report: dict, title: str, pictures: list[str]) -> str:
    s = report["sequence"]
    rel = s["max_deviation_relative"]
    worst = s["max_deviation_frame"]
    lines = [f"# Animation repair report{': ' + title if title else ''}", ""]
    lines += ["| sequence | |", "|---|---|"]
    figures = [
        ("frames", f"{s['frames']} ({s['repaired_frames']} repaired)"),
        ("unchanged frames", f"{s['unchanged_frames']} of {s['frames']}"),
        ("frames with new input crossings", str(s["frames_with_input_crossings"])),
        ("frames with new output crossings", str(s["frames_with_output_crossings"])),
        (
            "of them, outside the prescribed vertices",
            str(s["frames_with_output_crossings_outside_prescribed"]),
        ),
        (
            "max deviation",
            f"{_g(s['max_deviation'])}"
            + (f" ({100 * rel:.3g}% of the bbox diagonal)" if rel is not None else "")
            + (f" at frame {worst}" if worst is not None else ""),
        ),
        ("max coordinate deviation", _g(s["max_coordinate_deviation"])),
        ("mean deviation (mean over frames)", _g(s["mean_deviation"])),
        ("Newton iterations", f"{s['newton_iterations']} ({s['mean_newton_iterations_per_frame']:.3g} per frame)"),
        ("wall time", f"{s['wall_time']:.3g} s ({s['mean_seconds_per_frame']:.3g} s per frame)"),
        ("all certified", "yes" if s["all_certified"] else f"NO ({s['uncertified_frames']} frame(s) failed)"),
    ]
    lines += [f"| {k} | {v} |" for k, v in figures]
    if pictures:
        lines += ["", " ".join(f"![{p}]({p})" for p in pictures)]
    lines += [
        "",
        "Crossings: intersecting triangle pairs of the frame (in parentheses: those not among the first frame's "
        "preserved pairs; a `p` count: of those, pairs among prescribed vertices only, which follow the input's own "
        "crossings). Deviations |output − input| per vertex, in scene units.",
        "",
        "| frame | unchanged | input crossings (new) | output crossings (new) | max dev | mean dev | its | s |",
        "|---:|:---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in report["frames"]:
        frame = f"{r['frame']}" + (" (start)" if r["initial"] else "") + (" ✗" if r["certified"] is False else "")
        lines.append(
            f"| {frame} | {'yes' if r['unchanged'] else ''} "
            f"| {r['input_crossing_pairs']} ({r['input_crossing_pairs_not_preserved']}) "
            f"| {r['output_crossing_pairs']} ({r['output_crossing_pairs_not_preserved']}"
            + (f", {r['output_crossing_pairs_prescribed']} p" if r["output_crossing_pairs_prescribed"] else "")
            + ") "
            f"| {_g(r['max_deviation'])} | {_g(r['mean_deviation'])} "
            f"| {r['newton_iterations']} | {r['wall_time']:.3g} |"
        )
    if any(r["certified"] is False for r in report["frames"]):
        lines += ["", "✗: the frame failed the injectivity certificate."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------- deviation.png


def _save(fig: Figure, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, dpi=fig.dpi, format="png", facecolor="white")
    os.replace(tmp, path)


def _plot_deviation(path: Path, rows: list[dict], title: str) -> None:
    frames = np.array([r["frame"] for r in rows], dtype=float)
    dmax = np.array([r["max_deviation"] for r in rows])
    dmean = np.array([r["mean_deviation"] for r in rows])
    unchanged = np.array([r["unchanged"] for r in rows], dtype=bool)
    new_in = np.array([r["input_crossing_pairs_not_preserved"] for r in rows])
    new_out = np.array([r["output_crossing_pairs_not_preserved"] for r in rows])
    new_out_prescribed = np.array([r["output_crossing_pairs_prescribed"] for r in rows])
    fig = Figure(figsize=(9.0, 6.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.plot(frames, dmax, "-", color="#C44E52", lw=1.4, label="max deviation", zorder=2)
    ax1.plot(frames, dmean, "-", color="#4C72B0", lw=1.4, label="mean deviation", zorder=2)
    ax1.plot(frames[~unchanged], dmax[~unchanged], "o", color="#C44E52", ms=3.5, zorder=3)
    ax1.plot(frames[~unchanged], dmean[~unchanged], "o", color="#4C72B0", ms=3.5, zorder=3)
    if unchanged.any():
        ax1.plot(
            frames[unchanged], dmax[unchanged], "o", mfc="none", mec="#B0B0B0", ms=4.5, zorder=3, label="unchanged"
        )
    ax1.set_ylabel("deviation (scene units)")
    ax1.set_ylim(bottom=0.0, top=max(float(dmax.max(initial=0.0)) * 1.08, 1e-12))
    diag = [r["max_deviation"] / r["max_deviation_relative"] for r in rows if r["max_deviation_relative"]]
    if diag and diag[0] > 0:
        d = float(diag[0])
        sec = ax1.secondary_yaxis("right", functions=(lambda y: 100.0 * y / d, lambda p: p * d / 100.0))
        sec.set_ylabel("% of bbox diagonal")
    ax1.legend(loc="upper left", fontsize=8, frameon=False)
    ax1.grid(alpha=0.3)
    width = 0.4 if len(frames) < 2 else 0.4 * float(np.min(np.diff(np.unique(frames))))
    ax2.bar(frames - width / 2, new_in, width=width, color="#DD8452", label="input crossing pairs not preserved")
    ax2.bar(
        frames + width / 2,
        new_out - new_out_prescribed,
        width=width,
        color="#C44E52",
        label="output crossing pairs not preserved",
    )
    if new_out_prescribed.any():  # the prescribed parts' own crossings, as in the input (prescribed_contact)
        ax2.bar(
            frames + width / 2,
            new_out_prescribed,
            bottom=new_out - new_out_prescribed,
            width=width,
            color="#8172B3",
            label="… among prescribed vertices only (as in the input)",
        )
    if unchanged.any():
        ax2.plot(frames[unchanged], np.zeros(int(unchanged.sum())), "o", mfc="none", mec="#B0B0B0", ms=4.5)
    ax2.set_ylim(bottom=0.0, top=max(float(max(new_in.max(initial=0), new_out.max(initial=0))) * 1.1, 1.0))
    ax2.set_ylabel("crossing pairs")
    ax2.set_xlabel("frame")
    ax2.legend(loc="upper left", fontsize=8, frameon=False)
    ax2.grid(alpha=0.3)
    fig.suptitle(f"Animation repair{': ' + title if title else ''}", fontsize=11)
    fig.tight_layout()
    _save(fig, path)


# -------------------------------------------------------------------------------------------------- worst_frame.png


def _view(x: np.ndarray, faces: np.ndarray, dev: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right, up, towards-eye unit vectors: "up" is the bounding box's longest axis (a standing figure stands),
    the eye looks at the changed region's side (deviation- and area-weighted mean normal), a little from above."""
    ext = x.max(0) - x.min(0) if x.size else np.ones(3)
    up = np.zeros(3)
    up[int(np.argmax(ext))] = 1.0
    tri = x[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted normals
    w = dev[faces].mean(axis=1)
    look = (n * w[:, None]).sum(0) if w.any() else np.zeros(3)
    look = look - (look @ up) * up
    if np.linalg.norm(look) < 1e-12 * max(float(np.abs(n).sum()), 1e-300):
        look = np.roll(up, 1) + 0.6 * np.roll(up, 2)  # a default three-quarter view
    look = look / np.linalg.norm(look)
    side = np.cross(up, look)
    eye = look + 0.35 * side + 0.3 * up
    eye /= np.linalg.norm(eye)
    right = np.cross(up, eye)
    right /= np.linalg.norm(right)
    return right, np.cross(eye, right), eye


def _panel(ax, x: np.ndarray, faces: np.ndarray, fdev: np.ndarray, cam, norm: Normalize | None) -> np.ndarray:
    """Draw a two-sided, Lambert-shaded surface in painter's order, faces coloured by ``fdev`` (grey where 0);
    return the projected points used."""
    right, up, eye = cam
    if faces.shape[0] == 0:
        return np.zeros((0, 2))
    light = -0.35 * right + 0.55 * up + 0.75 * eye
    light /= np.linalg.norm(light)
    proj = np.stack([x @ right, x @ up], axis=1)
    tri = x[faces]
    nrm = _normals(tri)
    nrm = np.where((nrm @ eye < 0)[:, None], -nrm, nrm)  # both sides of open surfaces (garments) show
    lam = 0.4 + 0.6 * np.clip(nrm @ light, 0.0, None)
    base = np.broadcast_to(_GREY, (faces.shape[0], 3)).copy()
    if norm is not None:
        changed = fdev > 0
        base[changed] = colormaps[_CMAP](norm(fdev[changed]))[:, :3]
    rgba = np.ones((faces.shape[0], 4))
    rgba[:, :3] = np.clip(base * lam[:, None], 0.0, 1.0)
    order = np.argsort((x @ eye)[faces].mean(axis=1), kind="stable")  # far first
    polys, cols = proj[faces[order]], rgba[order]
    if faces.shape[0] <= _DENSE:
        edges = cols.copy()
        edges[:, :3] *= 0.6
        style: dict[str, Any] = dict(edgecolors=edges, linewidths=0.3)
    else:
        style = dict(edgecolors="none", linewidths=0.0, antialiased=False)
    ax.add_collection(PolyCollection(polys, facecolors=cols, snap=False, **style))
    return proj[np.unique(faces)]


def _limits(ax, pts: np.ndarray, aspect: float) -> None:
    lo, hi = (pts.min(0), pts.max(0)) if pts.size else (np.zeros(2), np.ones(2))
    pad = 0.04 * max(float((hi - lo).max()), 1e-12)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 + pad
    if half[0] / half[1] < aspect:
        half[0] = half[1] * aspect
    else:
        half[1] = half[0] / aspect
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_axis_off()


def _plot_worst(
    path: Path, frame: int, x_in: np.ndarray, x_out: np.ndarray, faces: np.ndarray, title: str, changed: bool
) -> None:
    dev = np.linalg.norm(x_out - x_in, axis=1)
    dmax = float(dev.max(initial=0.0))
    changed = changed and dmax > 0
    fdev = dev[faces].max(axis=1) if faces.size else np.zeros(0)  # the peak reaches the colour bar's top
    norm = Normalize(vmin=0.0, vmax=dmax) if changed else None
    cam = _view(x_out, faces, dev)
    inside = np.zeros(faces.shape[0], dtype=bool)
    if changed:
        hot = dev > _ZOOM_FRACTION * dmax
        lo, hi = x_out[hot].min(0), x_out[hot].max(0)
        lo = np.minimum(lo, x_in[hot].min(0))
        hi = np.maximum(hi, x_in[hot].max(0))
        pad = 0.25 * float((hi - lo).max()) + 2.0 * dmax
        centroid = x_out[faces].mean(axis=1)
        inside = np.all((centroid >= lo - pad) & (centroid <= hi + pad), axis=1)
    panels = 3 if inside.any() else 2
    size = (600 * panels, 640)
    dpi = 100
    fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    right_margin = 0.9 if changed else 0.99
    fig.subplots_adjust(left=0.01, right=right_margin, bottom=0.02, top=0.88, wspace=0.03)
    axes = [fig.add_subplot(1, panels, k + 1) for k in range(panels)]
    pos = axes[0].get_position()
    aspect = (pos.width * size[0]) / max(pos.height * size[1], 1e-9)
    p_in = _panel(axes[0], x_in, faces, fdev, cam, norm)
    p_out = _panel(axes[1], x_out, faces, fdev, cam, norm)
    both = np.concatenate([p_in, p_out])
    for ax in axes[:2]:
        _limits(ax, both, aspect)
    axes[0].set_title(f"input frame {frame}", fontsize=11)
    axes[1].set_title(f"repaired frame {frame}", fontsize=11)
    if panels == 3:
        pz = _panel(axes[2], x_out, faces[inside], fdev[inside], cam, norm)
        _limits(axes[2], pz, aspect)
        axes[2].set_title(f"repaired, zoom (deviation > {_ZOOM_FRACTION:.0%} of max)", fontsize=11)
    if changed and norm is not None:
        cax = fig.add_axes((0.92, 0.12, 0.015, 0.66))
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=_CMAP), cax=cax)
        bar.set_label("deviation |output − input| (scene units)")
        head = f"largest deviation: frame {frame}, max {dmax:.3g}"
    else:
        head = f"no frame changed (frame {frame} shown)"
    fig.suptitle(f"{title + ' — ' if title else ''}{head}", fontsize=12)
    _save(fig, path)


# -------------------------------------------------------------------------------------------------------- entry


def write_repair_report(
    out_dir: Path,
    records: list[dict],
    summary: dict,
    *,
    faces: np.ndarray,
    read_input: Callable[[int], np.ndarray],
    read_output: Callable[[int], np.ndarray],
    title: str = "",
) -> dict:
    """Write ``report.json``, ``report.md``, ``deviation.png`` and ``worst_frame.png`` into ``out_dir``.

    ``records``: the per-step records of ``stats.json`` (those without a ``"repair"`` dict are ignored; the first
    ``"initial"`` record is the start frame, later initial ones count only where no regular record of their step
    exists); ``summary``: its summary; ``faces`` (m, 3): the sequence's triangles; ``read_input(frame)`` /
    ``read_output(frame)``: (n, 3) vertices of an input and a repaired frame, read for the worst frame only.
    Returns the report (the content of ``report.json``). A picture that fails to draw is logged as a warning.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = [_row(r) for r in _select(records)]
    report: dict[str, Any] = {"frames": rows, "sequence": _sequence(rows, summary)}
    _write_text(out_dir / "report.json", json.dumps(to_jsonable(report), indent=1, allow_nan=False) + "\n")

    pictures = []
    if rows:
        try:
            _plot_deviation(out_dir / "deviation.png", rows, title)
            pictures.append("deviation.png")
        except Exception as exc:  # a picture must never lose the report
            log.warning("could not render deviation.png: %s", exc)
        try:
            seq = report["sequence"]
            worst = seq["max_deviation_frame"]
            frame = int(worst) if worst is not None else rows[-1]["frame"]
            x_in = np.asarray(read_input(frame), dtype=np.float64)
            x_out = np.asarray(read_output(frame), dtype=np.float64)
            f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
            _plot_worst(out_dir / "worst_frame.png", frame, x_in, x_out, f, title, worst is not None)
            pictures.append("worst_frame.png")
        except Exception as exc:
            log.warning("could not render worst_frame.png: %s", exc)
    _write_text(out_dir / "report.md", _markdown(report, title, pictures))
    return report


__all__ = ["write_repair_report"]
