"""Report of ``idp uv`` (paper §7.4): how much the worst-case distortion of a UV map improved.

The distortion of a UV triangle is the symmetric Dirichlet energy density Ψ = ‖F‖²_F + ‖F⁻¹‖²_F of the UV map's
Jacobian F = Ds Dm⁻¹ (4 for an isometry, +∞ for a flipped or collapsed triangle). :func:`write_uv_report` writes

* ``report.json``: before/after summaries (worst, 99th percentile, area-weighted mean, median), flipped
  triangles and overlapping pairs after, and the run's own figures (``extra``);
* ``report.md``: the same as a Markdown table;
* ``distortion.png``: the layouts before and after side by side, triangles coloured by Ψ on one shared log scale;
* ``distortion_hist.png``: histograms of Ψ before and after.

Pictures are drawn headless (matplotlib Agg through :class:`FigureCanvasAgg`, as :mod:`idp.output.repair_report`);
a failure to draw one is logged and never loses the JSON and Markdown.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import PolyCollection
from matplotlib.colors import LogNorm, to_rgba
from matplotlib.figure import Figure

from idp.mesh.distortion import distortion_summary
from idp.mesh.distortion import symmetric_dirichlet_distortion as _psi_of_F
from idp.mesh.uv_obj import UVMesh, uv_overlaps, uv_signed_areas
from idp.output.stats import to_jsonable

log = logging.getLogger("idp")

_CMAP = "viridis"
_MARK = "#FF2D2D"  # triangles with Ψ = +∞ (flipped or collapsed), and the ring around the worst triangle
_ISOMETRIC = 4.0


# -------------------------------------------------------------------------------------------------- distortion


def symmetric_dirichlet_distortion(uv: np.ndarray, faces_uv: np.ndarray, Dm: np.ndarray) -> np.ndarray:
    """Ψ = ‖F‖²_F + ‖F⁻¹‖²_F per UV triangle (m,), F = Ds Dm⁻¹ with Ds's columns uv1 − uv0, uv2 − uv0; 4 for an
    isometry, +∞ where the UV triangle is flipped or has no area."""
    t = np.asarray(uv, dtype=np.float64)[np.asarray(faces_uv, dtype=np.int64)]
    ds = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]], axis=2)  # columns are the edges
    return _psi_of_F(ds @ np.linalg.inv(np.asarray(Dm, dtype=np.float64)))


# ------------------------------------------------------------------------------------------------------ files


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _g(v: Any, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, float) and math.isinf(v):
        return "∞"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def _markdown(report: dict, title: str, pictures: list[str]) -> str:
    b, a = report["before"], report["after"]
    lines = [f"# UV distortion report{': ' + title if title else ''}", ""]
    lines += [
        "Symmetric Dirichlet distortion Ψ = ‖F‖² + ‖F⁻¹‖² per triangle (4 = isometric, ∞ = flipped); "
        "mean weighted by 3D area.",
        "",
        "| | before | after |",
        "|---|---:|---:|",
    ]
    for key, label in (("worst", "worst Ψ"), ("p99", "99th percentile"), ("mean", "mean"), ("median", "median")):
        lines.append(f"| {label} | {_g(b[key])} | {_g(a[key])} |")
    lines.append(f"| flipped triangles | {report['flipped_before']} | {report['flipped_after']} |")
    lines.append(f"| overlapping pairs | {report['overlapping_pairs_before']} | {report['overlapping_pairs_after']} |")
    lines.append(f"| triangles | {b['count']} | {a['count']} |")
    run = {k: v for k, v in report.items() if k not in _OWN_KEYS}
    if run:
        lines += ["", "| run | |", "|---|---|"]
        lines += [f"| {k} | {_g(v)} |" for k, v in run.items() if not isinstance(v, (dict, list))]
    if pictures:
        lines += ["", " ".join(f"![{p}]({p})" for p in pictures)]
    return "\n".join(lines) + "\n"


_OWN_KEYS = frozenset(
    {
        "before",
        "after",
        "source",
        "flipped_before",
        "flipped_after",
        "overlapping_pairs_before",
        "overlapping_pairs_after",
        "worst_improvement",
    }
)


# -------------------------------------------------------------------------------------------------- pictures


def _save(fig: Figure, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, dpi=fig.dpi, format="png", facecolor="white")
    os.replace(tmp, path)


def _scale(psi_before: np.ndarray, psi_after: np.ndarray) -> LogNorm:
    """One log scale for both panels, from isometric (4) to the larger finite worst: the few bad triangles get the
    bright end, the many good ones the dark one."""
    finite = np.concatenate([psi_before[np.isfinite(psi_before)], psi_after[np.isfinite(psi_after)]])
    top = float(finite.max()) if finite.size else _ISOMETRIC * 10.0
    return LogNorm(vmin=_ISOMETRIC, vmax=max(top, _ISOMETRIC * 1.01))


def _layout(ax: Axes, uv: np.ndarray, faces: np.ndarray, psi: np.ndarray, norm: LogNorm, label: str) -> None:
    """UV triangles coloured by Ψ, drawn from the best to the worst so that the worst stay on top; a ring marks the
    worst triangle (it may be too small to see)."""
    order = np.argsort(psi, kind="stable")
    colours = colormaps[_CMAP](norm(np.clip(psi[order], _ISOMETRIC, norm.vmax)))
    colours[np.isinf(psi[order])] = to_rgba(_MARK)
    dense = faces.shape[0] > 4000
    ax.add_collection(
        PolyCollection(
            uv[faces[order]],
            facecolors=colours,
            edgecolors="none" if dense else (0.15, 0.15, 0.15, 0.35),
            linewidths=0.0 if dense else 0.3,
            antialiased=not dense,
            rasterized=True,
        )
    )
    if faces.shape[0]:
        worst = int(order[-1])
        c = uv[faces[worst]].mean(axis=0)
        ax.plot([c[0]], [c[1]], "o", ms=14, mfc="none", mec=_MARK, mew=1.5)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    pad = 0.03 * max(float((hi - lo).max()), 1e-12)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(label, fontsize=10)


def _caption(name: str, s: dict) -> str:
    return f"{name}: worst {_g(s['worst'])}, p99 {_g(s['p99'])}, mean {_g(s['mean'])}"


def _plot_layouts(
    path: Path,
    faces: np.ndarray,
    uv_before: np.ndarray,
    uv_after: np.ndarray,
    psi_b: np.ndarray,
    psi_a: np.ndarray,
    report: dict,
    title: str,
) -> None:
    norm = _scale(psi_b, psi_a)
    fig = Figure(figsize=(13.0, 6.4), dpi=110, facecolor="white")
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.01, right=0.9, bottom=0.03, top=0.88, wspace=0.05)
    ax_b, ax_a = fig.subplots(1, 2)
    _layout(ax_b, uv_before, faces, psi_b, norm, _caption("before", report["before"]))
    _layout(ax_a, uv_after, faces, psi_a, norm, _caption("after", report["after"]))
    cax = fig.add_axes((0.915, 0.12, 0.015, 0.7))
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=_CMAP), cax=cax)
    bar.set_label("symmetric Dirichlet Ψ (4 = isometric, log scale)")
    note = "ring: worst triangle" + (
        ", red: flipped" if report["before"]["infinite"] or report["after"]["infinite"] else ""
    )
    fig.suptitle(f"UV distortion{': ' + title if title else ''}  ({note})", fontsize=12)
    _save(fig, path)


def _plot_histogram(path: Path, psi_b: np.ndarray, psi_a: np.ndarray, title: str) -> None:
    fb, fa = psi_b[np.isfinite(psi_b)], psi_a[np.isfinite(psi_a)]
    top = max(float(fb.max(initial=_ISOMETRIC)), float(fa.max(initial=_ISOMETRIC)), _ISOMETRIC * 1.01)
    bins = np.geomspace(_ISOMETRIC, top * 1.0001, 61)
    fig = Figure(figsize=(8.0, 4.5), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for data, colour, label in ((fb, "#C44E52", "before"), (fa, "#4C72B0", "after")):
        if data.size:
            ax.hist(
                np.clip(data, _ISOMETRIC, None), bins=bins.tolist(), histtype="step", lw=1.6, color=colour, label=label
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("symmetric Dirichlet Ψ per triangle (4 = isometric)")
    ax.set_ylabel("triangles")
    ax.legend(frameon=False)
    ax.grid(alpha=0.3)
    ax.set_title(f"Distortion histogram{': ' + title if title else ''}", fontsize=11)
    fig.tight_layout()
    _save(fig, path)


# ------------------------------------------------------------------------------------------------------ entry


def write_uv_report(
    out_dir: str | os.PathLike,
    *,
    mesh: UVMesh,
    Dm: np.ndarray,
    areas: np.ndarray,
    uv_before: np.ndarray,
    uv_after: np.ndarray,
    extra: dict[str, Any] | None = None,
    title: str = "",
) -> dict[str, Any]:
    """Write ``report.json``, ``report.md``, ``distortion.png`` and ``distortion_hist.png`` into ``out_dir``.

    ``mesh``: the (oriented) mesh whose ``faces_uv`` index ``uv_before``/``uv_after`` (nt, 2) and whose
    ``faces_xyz`` gave ``Dm`` (m, 2, 2) and ``areas`` (m,) (:func:`idp.mesh.uv_obj.uv_rest_frames`); ``extra``:
    the run's figures (wall time, steps, Newton iterations, p, ...), merged into the report (a key the report
    already has keeps the report's value). Returns the report
    (the content of ``report.json``, before JSON conversion). A picture that fails to draw is logged.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    faces = np.asarray(mesh.faces_uv, dtype=np.int64)
    before = np.asarray(uv_before, dtype=np.float64)
    after = np.asarray(uv_after, dtype=np.float64)
    psi_b = symmetric_dirichlet_distortion(before, faces, Dm)
    psi_a = symmetric_dirichlet_distortion(after, faces, Dm)
    s_b, s_a = distortion_summary(psi_b, areas), distortion_summary(psi_a, areas)
    report: dict[str, Any] = {
        "source": mesh.source,
        "before": s_b,
        "after": s_a,
        "worst_improvement": (s_b["worst"] / s_a["worst"]) if s_a["worst"] and math.isfinite(s_a["worst"]) else None,
        "flipped_before": int((uv_signed_areas(before, faces) <= 0).sum()),
        "flipped_after": int((uv_signed_areas(after, faces) <= 0).sum()),
        "overlapping_pairs_before": len(uv_overlaps(before, faces)),
        "overlapping_pairs_after": len(uv_overlaps(after, faces)),
    }
    for key, value in (extra or {}).items():  # the run's figures; they never replace the report's own
        report.setdefault(key, value)
    _write_text(out / "report.json", json.dumps(to_jsonable(report), indent=1, allow_nan=False) + "\n")

    pictures = []
    try:
        _plot_layouts(out / "distortion.png", faces, before, after, psi_b, psi_a, report, title)
        pictures.append("distortion.png")
    except Exception as exc:  # a picture must never lose the report
        log.warning("could not render distortion.png: %s", exc)
    try:
        _plot_histogram(out / "distortion_hist.png", psi_b, psi_a, title)
        pictures.append("distortion_hist.png")
    except Exception as exc:
        log.warning("could not render distortion_hist.png: %s", exc)
    _write_text(out / "report.md", _markdown(report, title, pictures))
    return report


__all__ = ["distortion_summary", "symmetric_dirichlet_distortion", "write_uv_report"]
