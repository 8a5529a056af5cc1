"""Headless PNG snapshots of a scene (matplotlib Agg; no GPU, no display).

3D: our own orthographic camera (matplotlib's ``elev``/``azim`` convention) projects the
deformable surfaces to 2D; back faces are culled, the rest Lambert-shaded from a light fixed
to the camera and drawn in one PolyCollection in painter's order (far to near), so depth
ordering is global across parts. Obstacles that enclose the deformables (cages) are drawn
first, behind everything: only their back-facing half, as light translucent faces plus their
feature edges (creases), so the object inside stays clearly visible. Other obstacles are
drawn as opaque grey shaded surfaces inside the global depth sort.
2D: filled triangles per part and obstacle polylines.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure

from idp.output.parts import Part, check_parts

PALETTE = ["#4C72B0", "#DD8452", "#55A868", "#C44E52", "#8172B3", "#937860", "#DA8BC3", "#CCB974", "#64B5CD"]
_OBSTACLE_RGB = np.array([0.62, 0.62, 0.64])
_CAGE_EDGE = (0.25, 0.25, 0.28, 0.9)
_DENSE = 4000  # above this many faces per panel, no mesh edges are drawn


#: rotations taking a scene's up axis to +z (the camera's up), right-handed
UP_ROTATIONS = {
    "x": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "z": np.eye(3),
}


def _camera(view: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Right, up, towards-eye unit vectors and the light direction for (elev, azim) in degrees."""
    elev, azim = np.radians(view[0]), np.radians(view[1])
    eye = np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])
    right = np.array([-math.sin(azim), math.cos(azim), 0.0])
    up = np.cross(eye, right)
    light = -0.35 * right + 0.55 * up + 0.75 * eye
    return right, up, eye, light / np.linalg.norm(light)


def _normals(tri: np.ndarray) -> np.ndarray:
    """Unit normals of triangles (f, 3, 3); degenerate ones get a zero normal."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _feature_edges(
    faces: np.ndarray, normals: np.ndarray, back: np.ndarray, cos_max: float = math.cos(math.radians(10))
) -> np.ndarray:
    """Unique (e, 2) edges that are creases or borders and touch a back-facing triangle."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, inv, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    face_of = np.repeat(np.arange(faces.shape[0]), 3)
    order = np.argsort(inv, kind="stable")
    starts = np.cumsum(counts) - counts
    fa = face_of[order[starts]]
    fb = face_of[order[starts + np.minimum(counts, 2) - 1]]
    crease = np.einsum("ij,ij->i", normals[fa], normals[fb]) < cos_max
    feature = (counts != 2) | crease
    touches_back = np.zeros(uniq.shape[0], dtype=bool)
    np.logical_or.at(touches_back, inv, np.repeat(back, 3))
    return uniq[feature & touches_back]


def _grid(n: int, size: tuple[int, int]) -> tuple[int, int]:
    """Rows and columns that give the largest panels for ``n`` panels in ``size``."""
    best = (1, n)
    best_score = -1.0
    for rows in range(1, n + 1):
        cols = math.ceil(n / rows)
        score = min(size[0] / cols, size[1] / rows)
        if score > best_score:
            best, best_score = (rows, cols), score
    return best


def _encloses(obst: np.ndarray, inner: np.ndarray) -> bool:
    """Whether the bounding box of points ``obst`` contains that of ``inner``."""
    if obst.size == 0 or inner.size == 0:
        return False
    return bool((obst.min(0) <= inner.min(0)).all() and (obst.max(0) >= inner.max(0)).all())


def _panel_3d(ax, parts: list[Part], x: np.ndarray, cam, cages: list[bool]) -> np.ndarray:
    """Draw one 3D panel; return the projected 2D points used (for the shared limits)."""
    right, up, eye, light = cam
    proj = np.stack([x @ right, x @ up], axis=1)
    depth = x @ eye
    polys, colours, depths = [], [], []
    cage_polys, cage_cols, cage_edges = [], [], []
    used = []
    for i, p in enumerate(parts):
        if p.surface.shape[0] == 0:
            continue
        tri = x[p.surface]
        nrm = _normals(tri)
        facing = nrm @ eye
        used.append(proj[np.unique(p.surface)])
        if p.kind == "obstacle" and cages[i]:
            back = facing < 0
            shade = 0.75 + 0.25 * np.abs(nrm[back] @ light)
            rgba = np.empty((int(back.sum()), 4))
            rgba[:, :3] = np.clip(0.92 * shade[:, None], 0, 1)
            rgba[:, 3] = 0.22
            cage_polys.append(proj[p.surface[back]])
            cage_cols.append(rgba)
            cage_edges.append(proj[_feature_edges(p.surface, nrm, back)])
            continue
        front = facing > 0
        if p.kind == "shell":  # open surfaces show both sides: back faces drawn with their normal flipped
            front = np.ones_like(front)
            nrm = np.where((facing < 0)[:, None], -nrm, nrm)
        base = np.asarray(to_rgb(PALETTE[i % len(PALETTE)])) if p.kind != "obstacle" else _OBSTACLE_RGB
        lam = 0.38 + 0.62 * np.clip(nrm[front] @ light, 0.0, None) + 0.12 * np.clip(-(nrm[front] @ light), 0.0, None)
        rgba = np.ones((int(front.sum()), 4))
        rgba[:, :3] = np.clip(base[None, :] * lam[:, None], 0, 1)
        polys.append(proj[p.surface[front]])
        colours.append(rgba)
        depths.append(depth[p.surface[front]].mean(axis=1))
    for polys_c, cols_c in zip(cage_polys, cage_cols, strict=True):
        ax.add_collection(PolyCollection(polys_c, facecolors=cols_c, edgecolors="none", zorder=1))
    for segs in cage_edges:
        ax.add_collection(LineCollection(segs, colors=[_CAGE_EDGE], linewidths=0.9, zorder=2))
    if polys:
        allp = np.concatenate(polys)
        allc = np.concatenate(colours)
        order = np.argsort(np.concatenate(depths), kind="stable")  # far (small depth) first
        allp, allc = allp[order], allc[order]
        if allp.shape[0] <= _DENSE:  # antialiased faces with darker mesh edges (the edges hide seams)
            edges = allc.copy()
            edges[:, :3] *= 0.6
            style: dict[str, Any] = dict(edgecolors=edges, linewidths=0.3)
        else:  # dense: no edges (they moire) and no antialiasing (it leaves seams between tiny faces)
            style = dict(edgecolors="none", linewidths=0.0, antialiased=False)
        # an (N, k, 2) array is PolyCollection's fast path; matplotlib's stub only names Sequence
        ax.add_collection(PolyCollection(allp, facecolors=allc, zorder=3, snap=False, **style))  # type: ignore[arg-type]
    return np.concatenate(used) if used else np.zeros((0, 2))


def _panel_2d(ax, parts: list[Part], x: np.ndarray) -> np.ndarray:
    """Draw one 2D panel; return the points used (for the shared limits)."""
    used = []
    for i, p in enumerate(parts):
        if p.kind == "deformable" and p.elements is not None and p.elements.shape[0]:
            tri = x[p.elements]
            rgb = np.asarray(to_rgb(PALETTE[i % len(PALETTE)]))
            if tri.shape[0] > _DENSE:
                style: dict[str, Any] = dict(edgecolors="none", linewidths=0.0, antialiased=False)
            else:
                style = dict(edgecolors=[rgb * 0.6], linewidths=0.4)
            ax.add_collection(PolyCollection(tri, facecolors=[rgb], zorder=2, snap=False, **style))
            used.append(tri.reshape(-1, 2))
        if p.surface.shape[0]:
            segs = x[p.surface]
            if p.kind == "obstacle":
                ax.add_collection(LineCollection(segs, colors=[_CAGE_EDGE], linewidths=1.4, zorder=3))
            else:  # outline of the deformable
                rgb = np.asarray(to_rgb(PALETTE[i % len(PALETTE)])) * 0.5
                ax.add_collection(LineCollection(segs, colors=[rgb], linewidths=0.8, zorder=3))
            used.append(segs.reshape(-1, 2))
    return np.concatenate(used) if used else np.zeros((0, 2))


def render_frames_png(
    path: str | Path,
    parts: list[Part],
    frames: list[tuple[str, np.ndarray]],
    *,
    dim: int,
    view: tuple[float, float] = (20, -60),
    size: tuple[int, int] = (1200, 600),
    up: str = "z",
    views: list[tuple[float, float]] | None = None,
) -> None:
    """Render ``frames`` ([(title, x), ...], x (n, dim) global positions) side by side into one PNG.

    All panels share the camera (``view`` = (elevation, azimuth) in degrees, 3D only) and the
    axis limits; ``size`` is the PNG size in pixels (width, height). ``views`` (3D): one camera per panel
    instead, e.g. one shape seen from several sides, each panel framing its own view.
    """
    if not frames:
        raise ValueError("render_frames_png needs at least one frame")
    if views is not None and len(views) != len(frames):
        raise ValueError(f"views: one (elevation, azimuth) per frame, got {len(views)} for {len(frames)} frames")
    need = check_parts(parts, dim)
    xs = []
    for title, x in frames:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] < dim or x.shape[0] < need:
            raise ValueError(f"frame {title!r}: x must be (n>={need}, {dim}), got {x.shape}")
        xs.append(x[:, :dim])
    if dim == 3 and up != "z":  # a rotation that takes the scene's up axis to the camera's z
        if up not in UP_ROTATIONS:
            raise ValueError(f"up must be one of x, y, z, got {up!r}")
        xs = [x @ UP_ROTATIONS[up].T for x in xs]
    dpi = 100
    fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    rows, cols = _grid(len(frames), size)
    top = max(1.0 - 30.0 / size[1], 0.5)  # room for the first row's titles
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=top, wspace=0.02, hspace=30.0 * rows / size[1] + 0.02)
    cam = _camera(view) if dim == 3 else None
    cages = [False] * len(parts)
    if dim == 3:
        deform = [xs[0][np.unique(p.surface)] for p in parts if p.kind in ("deformable", "shell") and p.surface.size]
        inner = np.concatenate(deform) if deform else np.zeros((0, 3))
        cages = [p.kind == "obstacle" and _encloses(xs[0][np.unique(p.surface)], inner) for p in parts]
    axes, pts = [], []
    for k, ((title, _), x) in enumerate(zip(frames, xs, strict=True)):
        ax = fig.add_subplot(rows, cols, k + 1)
        cam_k = _camera(views[k]) if dim == 3 and views is not None else cam
        pts.append(_panel_3d(ax, parts, x, cam_k, cages) if dim == 3 else _panel_2d(ax, parts, x))
        ax.set_title(str(title), fontsize=11)
        ax.set_axis_off()
        axes.append(ax)
    pos = axes[0].get_position()
    panel_aspect = (pos.width * size[0]) / max(pos.height * size[1], 1e-9)
    # one set of limits for all panels (frames compared in one camera), or each its own (one shape, several views)
    groups = [[k] for k in range(len(axes))] if views is not None else [list(range(len(axes)))]
    for group in groups:
        gpts = np.concatenate([pts[k] for k in group])
        if gpts.size:
            lo, hi = gpts.min(0), gpts.max(0)
        else:
            lo, hi = np.zeros(2), np.ones(2)
        pad = 0.04 * max(float((hi - lo).max()), 1e-12)
        lo, hi = lo - pad, hi + pad
        # widen the limits to the panel's pixel aspect so "equal" needs no box shrinking
        centre, half = (lo + hi) / 2, (hi - lo) / 2
        if half[0] / half[1] < panel_aspect:
            half[0] = half[1] * panel_aspect
        else:
            half[1] = half[0] / panel_aspect
        for k in group:
            axes[k].set_xlim(centre[0] - half[0], centre[0] + half[0])
            axes[k].set_ylim(centre[1] - half[1], centre[1] + half[1])
            axes[k].set_aspect("equal", adjustable="box")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, dpi=dpi, format="png", facecolor="white")
    os.replace(tmp, path)
