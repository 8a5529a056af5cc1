"""Pictures and a summary table of the paper-figure runs (Figs. 3, 10, 19 and 20) from their output folders.

    python bench/paper_figures.py fig10 OUT_PLASTIC OUT_ELASTIC OUT_NOBARRIER -o docs/figures/fig10_bar.png
    python bench/paper_figures.py fig03 OUT_ARMADILLO -o docs/figures/fig03_armadillo.png --frames 0 25 54 120
    python bench/paper_figures.py fig19 OUT_DISK_P1 OUT_DISK_P10 -o docs/figures/fig19_disk.png
    python bench/paper_figures.py fig20 OUT_ARM_P1 OUT_ARM_P5 -o docs/figures/fig20_arm.png --view 30 -80
    python bench/paper_figures.py table OUT... > table.md

Positions are read back from each run's VTU frames (every point of the scene) and drawn with the parts of the
scene the run resolved (``scene.resolved.json``), so the pictures show exactly what was written and certified.

Figs. 19 and 20 (min-max distortion, §7.4) colour the last VTU frame of each run by its per-element cell field
``distortion`` (symmetric Dirichlet Ψ; 4 is an isometry in 2D, 6 in 3D) on one log colour scale shared by all
panels, from the isometry value to the largest worst Ψ; titles give p and the frame's worst/p99/mean Ψ from
``stats.json``. Fig. 19 draws the 2D triangles with the worst one ringed; Fig. 20 draws the boundary surface of
the tets (each face coloured by its tet, Lambert-shaded) and, below it, the section of the tets by the plane
halfway through the z-extent, viewed along z, so the stress concentrations inside the bend show.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import meshio
import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator, MaxNLocator, NullLocator

from idp.output.render import _DENSE, _camera, _normals, render_frames_png
from idp.output.stats import load_stats
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _parts(run: Path):
    resolved = json.loads((run / "scene.resolved.json").read_text())
    return build_scene(scene_from_dict(resolved)).system.parts


def _frame(run: Path, step: int) -> np.ndarray:
    return meshio.read(run / "vtu" / f"frame_{step:05d}.vtu").points


def _last_step(run: Path) -> int:
    return int(load_stats(run / "stats.json")["summary"]["last_step"])


def summary_row(run: Path) -> str:
    st = load_stats(run / "stats.json")
    s, recs = st["summary"], [r for r in st["steps"] if not r.get("initial")]
    pairs = max((r["certificate"].get("intersecting_pairs", 0) for r in recs), default=0)
    guarded = all(r["certificate"].get("guards_intersection", True) for r in recs)
    mind = s["min_distance"]
    return (
        f"| {st['meta'].get('scene', run.name)} | {s['steps_run']} | {s['wall_time']:.0f} | {s['newton_iterations']} "
        f"| {s.get('steps_with_unmet_targets', 0)} | {mind if isinstance(mind, str) else f'{mind:.2e}'} "
        f"| {'yes' if s['all_certified'] and guarded else ('no barrier: ' + str(pairs) + ' crossing pairs max')} |"
    )


# ---- Figs. 19 and 20: per-element distortion Ψ of min-max runs -------------------------------------------------

_CMAP = "viridis"
_RING = "#E8112D"  # marks the worst element
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])  # face k is opposite vertex k


def _distortion_frame(run: Path, cell_type: str) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Step, points, ``cell_type`` cells and their Ψ of the run's last VTU frame (frame 0 carries no Ψ)."""
    path = max((run / "vtu").glob("frame_*.vtu"))
    mesh = meshio.read(path)
    cells, psi = [], []
    for block, field in zip(mesh.cells, mesh.cell_data["distortion"], strict=True):
        if block.type == cell_type:
            cells.append(block.data)
            psi.append(np.asarray(field, dtype=np.float64))
    if not cells:
        raise ValueError(f"{path}: no {cell_type} cells")
    return (
        int(path.stem.split("_")[1]),
        np.asarray(mesh.points, dtype=np.float64),
        np.concatenate(cells),
        np.concatenate(psi),
    )


def _distortion_stats(run: Path, step: int) -> tuple[dict, dict]:
    """The run's stats and the distortion record (worst/p99/mean) of ``step`` (else of the last step)."""
    st = load_stats(run / "stats.json")
    rec = next((r for r in st["steps"] if r.get("step") == step and "distortion" in r), st["steps"][-1])
    return st, rec["distortion"]


def _power_label(st: dict) -> str:
    """The default panel label, "p = …", from the symmetric-Dirichlet power of the deformable objects."""
    objs = st["meta"].get("resolved_scene", {}).get("objects", [])
    powers = sorted({float(o["material"].get("power", 1.0)) for o in objs if o.get("kind") == "deformable"})
    return "p = " + ", ".join(f"{p:g}" for p in powers) if powers else "p = ?"


def _panel_title(label: str, d: dict) -> str:
    return f"{label}\nΨ worst {d['worst']:.4g}   p99 {d['p99']:.4g}   mean {d['mean']:.4g}"


def _ticks(lo: float, hi: float) -> list[float]:
    """Round colour-bar ticks in [lo, hi] that read on a log axis, ``lo`` (the isometry) and ``hi`` included."""
    if hi / lo < 2.0:  # a narrow range: evenly spaced round values
        room = 0.06 * (hi - lo)
        inner = [float(t) for t in MaxNLocator(5).tick_values(lo, hi) if lo + room < t < hi - room]
    else:
        nice = sorted({m * 10.0**e for e in range(-1, 9) for m in (1, 1.5, 2, 3, 5, 7)})
        room = (hi / lo) ** 0.06  # inner ticks keep 6% of the axis from the end ticks
        inner = [t for t in nice if lo * room < t < hi / room]
        while len(inner) > 8:
            inner = inner[::2]
    return [lo, *inner, hi]


def _colour_bar(fig: Figure, norm: LogNorm, rect: tuple[float, float, float, float], label: str) -> None:
    """The colour bar of the shared scale ``norm`` in ``rect`` (figure fractions)."""
    assert norm.vmin is not None and norm.vmax is not None
    cb = fig.colorbar(ScalarMappable(norm=norm, cmap=_CMAP), cax=fig.add_axes(rect))
    ticks = _ticks(float(norm.vmin), float(norm.vmax))
    cb.ax.yaxis.set_major_locator(FixedLocator(ticks))
    cb.ax.yaxis.set_minor_locator(NullLocator())
    cb.ax.set_yticklabels([f"{t:.3g}" for t in ticks])
    cb.ax.tick_params(labelsize=9)
    cb.set_label(label, fontsize=10)


def _shared_limits(axes: list, pts: list[np.ndarray], pad: float = 0.04) -> None:
    """One equal-aspect box around all ``pts`` for every axis in ``axes``."""
    allpts = np.concatenate(pts)
    lo, hi = allpts.min(0), allpts.max(0)
    margin = pad * max(float((hi - lo).max()), 1e-12)
    for ax in axes:
        ax.set_xlim(lo[0] - margin, hi[0] + margin)
        ax.set_ylim(lo[1] - margin, hi[1] + margin)
        ax.set_aspect("equal", adjustable="box")
        ax.set_axis_off()


def _ring(ax, xy: np.ndarray) -> None:
    ax.plot([xy[0]], [xy[1]], "o", ms=16, mfc="none", mec=_RING, mew=2.0, zorder=5)


def _save(fig: Figure, path: Path) -> None:
    """Write ``path`` (format from its suffix; the collections are rasterized in vector formats)."""
    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, dpi=fig.dpi, format=path.suffix.lstrip(".") or "png", facecolor="white")
    tmp.replace(path)


def _fill_style(n: int, face_rgba: np.ndarray) -> dict[str, Any]:
    """Thin darker edges for coarse meshes; none (and no antialiasing, which leaves seams) for dense ones."""
    if n > _DENSE:
        return dict(edgecolors="none", linewidths=0.0, antialiased=False)
    edges = face_rgba.copy()
    edges[:, :3] *= 0.7
    return dict(edgecolors=edges, linewidths=0.2)


def fig19(runs: list[Path], labels: list[str] | None, out: Path) -> None:
    """2D triangle meshes coloured by Ψ, side by side on one log scale from 4 (isometry) to the largest worst."""
    data = []
    for k, run in enumerate(runs):
        step, x, tri, psi = _distortion_frame(run, "triangle")
        st, d = _distortion_stats(run, step)
        data.append((labels[k] if labels else _power_label(st), d, x[:, :2], tri, psi))
    vmax = max(max(float(d["worst"]), float(psi.max())) for _, d, _, _, psi in data)
    norm = LogNorm(vmin=4.0, vmax=max(vmax, 4.0 * 1.001), clip=True)
    cmap = colormaps[_CMAP]
    n = len(data)
    fig = Figure(figsize=(4.6 * n + 1.0, 5.2), dpi=200, facecolor="white")
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.01, right=1.0 - 1.0 / (4.6 * n + 1.0), bottom=0.02, top=0.86, wspace=0.04)
    axes, pts = [], []
    for k, (label, d, x, tri, psi) in enumerate(data):
        ax = fig.add_subplot(1, n, k + 1)
        polys = x[tri]
        rgba = cmap(norm(psi))
        ax.add_collection(
            PolyCollection(polys, facecolors=rgba, rasterized=True, snap=False, **_fill_style(len(tri), rgba))
        )
        edges = np.sort(tri[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        uniq, counts = np.unique(edges, axis=0, return_counts=True)
        ax.add_collection(LineCollection(x[uniq[counts == 1]], colors="0.15", linewidths=0.6, zorder=3))
        _ring(ax, polys[int(np.argmax(psi))].mean(axis=0))
        ax.set_title(_panel_title(label, d), fontsize=11)
        axes.append(ax)
        pts.append(x[np.unique(tri)])
    _shared_limits(axes, pts)
    w = 1.0 / (4.6 * n + 1.0)
    _colour_bar(fig, norm, (1.0 - 0.8 * w, 0.1, 0.18 * w, 0.72), "Ψ (log; 4 = isometry)")
    _save(fig, out)


def _boundary_faces(x: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward-oriented boundary triangles of a tet mesh (faces of one tet only) and the tet each belongs to."""
    faces = tets[:, _TET_FACES].reshape(-1, 3)
    owner = np.repeat(np.arange(tets.shape[0]), 4)
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    keep = counts[inv.reshape(-1)] == 1
    faces, owner = faces[keep], owner[keep]
    opposite = tets[owner, np.tile(np.arange(4), tets.shape[0])[keep]]
    nrm = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    inward = np.einsum("ij,ij->i", nrm, x[opposite] - x[faces[:, 0]]) > 0
    faces[inward] = faces[inward][:, ::-1]
    return faces, owner


def _section(x: np.ndarray, tets: np.ndarray, z0: float) -> tuple[np.ndarray, np.ndarray]:
    """The convex (x, y) polygons (N, 4, 2; triangles repeat a corner) in which the plane z = z0 cuts the tets."""
    s = x[tets][:, :, 2] - z0
    above = s > 0
    cut = (above.any(axis=1)) & (~above).any(axis=1)
    t_ids = np.flatnonzero(cut)
    s, above, tv = s[cut], above[cut], tets[cut]
    ei, ej = np.array([0, 0, 0, 1, 1, 2]), np.array([1, 2, 3, 2, 3, 3])
    crosses = above[:, ei] != above[:, ej]  # (N, 6): three or four edges cross
    si, sj = s[:, ei], s[:, ej]
    t = np.divide(si, si - sj, out=np.zeros_like(si), where=crosses)
    xi, xj = x[tv[:, ei], :2], x[tv[:, ej], :2]
    p = xi + t[:, :, None] * (xj - xi)  # (N, 6, 2)
    centre = (p * crosses[:, :, None]).sum(1) / crosses.sum(1, keepdims=True)
    ang = np.arctan2(p[:, :, 1] - centre[:, None, 1], p[:, :, 0] - centre[:, None, 0])
    order = np.argsort(np.where(crosses, ang, np.inf), axis=1)[:, :4]
    poly = np.take_along_axis(p, order[:, :, None], axis=1)
    tri = crosses.sum(1) == 3
    poly[tri, 3] = poly[tri, 2]
    return poly, t_ids


def _z_label(z0: float, extent: float) -> str:
    """``z0`` as 0 when within a thousandth of the z-extent of it (a mid-plane at 5e-6 reads as 0)."""
    return "0" if abs(z0) < 1e-3 * extent else f"{z0:.3g}"


def fig20(runs: list[Path], labels: list[str] | None, out: Path, view: tuple[float, float]) -> None:
    """3D tet meshes: Ψ on the boundary surface (top row) and on the mid-z section (bottom row), one log scale."""
    data = []
    for k, run in enumerate(runs):
        step, x, tets, psi = _distortion_frame(run, "tetra")
        st, d = _distortion_stats(run, step)
        data.append((labels[k] if labels else _power_label(st), d, x, tets, psi))
    vmax = max(max(float(d["worst"]), float(psi.max())) for _, d, _, _, psi in data)
    norm = LogNorm(vmin=6.0, vmax=max(vmax, 6.0 * 1.001), clip=True)
    cmap = colormaps[_CMAP]
    right, up, eye, light = _camera(view)
    surf, cuts = [], []
    for label, d, x, tets, psi in data:
        # boundary surface, Lambert-shaded, back faces culled, painter's order (far first)
        faces, owner = _boundary_faces(x, tets)
        nrm = _normals(x[faces])
        front = nrm @ eye > 0
        faces, owner, nrm = faces[front], owner[front], nrm[front]
        order = np.argsort((x[faces] @ eye).mean(axis=1), kind="stable")
        faces, owner, nrm = faces[order], owner[order], nrm[order]
        proj = np.stack([x @ right, x @ up], axis=1)
        rgba = cmap(norm(psi[owner]))
        rgba[:, :3] *= (0.45 + 0.55 * np.clip(nrm @ light, 0.0, None))[:, None]
        worst = int(np.argmax(psi))
        surf.append((_panel_title(label, d), proj[faces], rgba, proj[tets[worst]].mean(axis=0)))
        # section by the plane halfway through the z-extent, seen along z (flat colours, unshaded)
        zlo, zhi = float(x[:, 2].min()), float(x[:, 2].max())
        z0 = 0.5 * (zlo + zhi)
        poly, t_ids = _section(x, tets, z0)
        here = int(t_ids[np.argmax(psi[t_ids])])
        title = f"section z = {_z_label(z0, zhi - zlo)}, seen along z: Ψ worst in it {psi[here]:.4g}"
        cuts.append((title, poly, cmap(norm(psi[t_ids])), x[tets[here], :2].mean(axis=0)))
    # layout in inches: equal-aspect rows as tall as the shared extents need (a bent arm is long and thin)
    n, panel_w, bar_w, gap = len(data), 4.8, 1.0, 0.1
    heights = []
    for row in (surf, cuts):
        pts = np.concatenate([polys.reshape(-1, 2) for _, polys, _, _ in row])
        ext = pts.max(0) - pts.min(0)
        heights.append(float(np.clip(panel_w * ext[1] / max(ext[0], 1e-12), 0.8, 1.6 * panel_w)))
    title_h = (0.6, 0.4)
    fig_w, fig_h = n * panel_w + (n - 1) * gap + bar_w, sum(heights) + sum(title_h) + 0.15
    fig = Figure(figsize=(fig_w, fig_h), dpi=200, facecolor="white")
    FigureCanvasAgg(fig)
    top = fig_h
    for r, (row, h, th) in enumerate(zip((surf, cuts), heights, title_h, strict=True)):
        top -= th + h
        axes, pts_row = [], []
        for k, (title, polys, rgba, ring) in enumerate(row):
            ax = fig.add_axes(((k * (panel_w + gap)) / fig_w, top / fig_h, panel_w / fig_w, h / fig_h))
            ax.add_collection(
                PolyCollection(polys, facecolors=rgba, rasterized=True, snap=False, **_fill_style(len(polys), rgba))
            )
            _ring(ax, ring)
            ax.set_title(title, fontsize=11 if r == 0 else 10)
            axes.append(ax)
            pts_row.append(polys.reshape(-1, 2))
        _shared_limits(axes, pts_row)
    bar_h = fig_h - 0.5
    _colour_bar(fig, norm, ((fig_w - 0.75) / fig_w, 0.2 / fig_h, 0.16 / fig_w, bar_h / fig_h), "Ψ (log; 6 = isometry)")
    _save(fig, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("fig10", "fig03", "fig19", "fig20", "table"))
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--frames", nargs="*", type=int, default=None)
    ap.add_argument("--view", nargs=2, type=float, default=None, help="elevation, azimuth (degrees) of 3D pictures")
    ap.add_argument("--labels", nargs="+", default=None, help="panel labels of fig19/fig20 (default: p = …)")
    a = ap.parse_args()
    if a.labels is not None and len(a.labels) != len(a.runs):
        ap.error(f"--labels: {len(a.labels)} labels for {len(a.runs)} runs")
    if a.what == "table":
        print("| scene | steps | wall (s) | Newton its | steps with unmet BC | min distance | every frame certified |")
        print("|---|---|---|---|---|---|---|")
        for r in a.runs:
            print(summary_row(r))
        return
    a.output.parent.mkdir(parents=True, exist_ok=True)
    view = tuple(a.view) if a.view else (20.0, -60.0)
    if a.what == "fig19":
        fig19(a.runs, a.labels, a.output)
    elif a.what == "fig20":
        fig20(a.runs, a.labels, a.output, tuple(a.view) if a.view else (35.0, -80.0))
    elif a.what == "fig10":
        parts = _parts(a.runs[0])
        titles = ["elasto-plastic, barrier", "elastic, barrier", "elastic, no barrier"]
        frames = [(t, _frame(r, _last_step(r))) for t, r in zip(titles, a.runs, strict=True)]
        render_frames_png(a.output, parts, frames, dim=3, view=view, size=(1500, 520))
    else:
        run = a.runs[0]
        parts = _parts(run)
        steps = a.frames or [0, _last_step(run)]
        frames = [(f"step {k}", _frame(run, k)) for k in steps]
        cols = len(frames)
        render_frames_png(a.output, parts, frames, dim=3, view=view, size=(380 * cols, 480))
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
