"""Pictures of a run from its VTU frames (``idp render``): chosen steps side by side with one camera, or one step
seen from several named cameras.

Everything comes from the frames themselves — each VTU holds one cell block per part (tets or 2D triangles for a
deformable body, boundary triangles or segments for a shell or an obstacle), a ``part_id`` per cell and a ``fixed``
flag per vertex — so any run folder or stage folder can be drawn without rebuilding its scene, however its meshes
were made (instanced, remeshed, read from an earlier stage). A surface block whose vertices are all fixed is drawn as
an obstacle, any other as a shell.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from idp.errors import OutputError
from idp.mesh.surface import boundary_faces
from idp.output.parts import Part

#: Named cameras, (elevation, azimuth) in degrees, around the picture's up axis.
VIEWS: dict[str, tuple[float, float]] = {
    "oblique": (30.0, -60.0),
    "side": (5.0, -90.0),
    "front": (5.0, 0.0),
    "above": (89.0, -90.0),
}

_FRAME = re.compile(r"^frame_(\d{5,})\.vtu$")


def frame_files(run_dir: str | Path) -> dict[int, Path]:
    """{step: VTU file} of the frames a run wrote (``RUN/vtu/frame_NNNNN.vtu``), in step order."""
    run = Path(run_dir)
    vtu = run / "vtu"
    if not vtu.is_dir():
        raise OutputError(f"{run}: no vtu/ folder of frames (a run writes it unless [output] vtu = false)")
    found = {int(m.group(1)): vtu / p.name for p in vtu.iterdir() if (m := _FRAME.match(p.name))}
    if not found:
        raise OutputError(f"{vtu}: no frame_NNNNN.vtu files")
    return dict(sorted(found.items()))


def _read_frame(path: str | Path):
    import meshio

    try:
        return meshio.read(path)
    except (Exception, SystemExit) as exc:  # meshio raises many kinds on a damaged file, or calls sys.exit
        raise OutputError(f"{path}: cannot be read as a VTU frame ({exc})") from exc


def _cell_counts(mesh) -> list[tuple[str, int]]:
    return [(block.type, len(block.data)) for block in mesh.cells]


def parts_from_frame(path: str | Path, dim: int) -> tuple[list[Part], np.ndarray]:
    """(parts, positions (n, dim)) of one VTU frame as idp writes them."""
    return _parts(_read_frame(path), path, dim)


def _parts(mesh, path: str | Path, dim: int) -> tuple[list[Part], np.ndarray]:
    x = np.asarray(mesh.points, dtype=np.float64)[:, :dim]
    fixed = np.asarray(mesh.point_data.get("fixed", np.zeros(len(x))), dtype=bool).reshape(-1)
    part_ids = mesh.cell_data.get("part_id")
    volume, surface = ("tetra", "triangle") if dim == 3 else ("triangle", "line")
    parts: list[Part] = []
    for k, block in enumerate(mesh.cells):
        all_cells = np.asarray(block.data, dtype=np.int64)
        if block.type not in (volume, surface) or all_cells.shape[0] == 0:
            continue
        if all_cells.min() < 0 or all_cells.max() >= len(x):
            raise OutputError(f"{path}: cell block {k} ({block.type}) refers to a vertex outside its {len(x)} points")
        # a VTU reader joins consecutive parts of one cell type into one block: split it by part_id again
        pid = np.asarray(part_ids[k]).reshape(-1) if part_ids is not None else np.full(all_cells.shape[0], k)
        if pid.shape[0] != all_cells.shape[0]:
            raise OutputError(f"{path}: part_id has {pid.shape[0]} values for {all_cells.shape[0]} {block.type} cells")
        for i in dict.fromkeys(pid.tolist()):  # parts in the order they come
            cells = all_cells[pid == i]
            ids = np.unique(cells)
            if block.type == volume:
                parts.append(Part(f"part {i}", "deformable", ids, cells, boundary_faces(cells)))
            else:
                kind = "obstacle" if fixed[ids].all() or dim == 2 else "shell"
                parts.append(Part(f"part {i}", kind, ids, None, cells))
    if not parts:
        raise OutputError(f"{path}: no {volume} or {surface} cells to draw")
    return parts, x


def render_run(
    run_dir: str | Path,
    out_png: str | Path,
    *,
    dim: int = 3,
    steps: list[int] | None = None,
    views: list[str] | None = None,
    up: str = "z",
    hide_obstacles: bool = False,
    size: tuple[int, int] | None = None,
) -> Path:
    """Draw a run's frames into ``out_png``. ``steps``: the steps to show (default: the first and the last frame
    written); ``views``: names from :data:`VIEWS` — the last of ``steps`` is then drawn once per camera (3D);
    otherwise one panel per step, one camera. ``hide_obstacles``: leave the obstacles (tools, cages) out."""
    from idp.output.render import render_frames_png

    frames = frame_files(run_dir)
    chosen = [min(frames), max(frames)] if not steps else list(steps)
    if chosen[0] == chosen[-1] and len(chosen) == 2:
        chosen = chosen[:1]
    missing = [k for k in chosen if k not in frames]
    if missing:
        have = list(frames)
        shown = ", ".join(map(str, have[:8])) + (f", … {have[-1]}" if len(have) > 8 else "")
        raise OutputError(f"{run_dir}: no frame for step(s) {missing} (frames written: {shown})")
    if views:
        unknown = [v for v in views if v not in VIEWS]
        if unknown:
            raise OutputError(f"unknown view(s) {unknown}: choose from {sorted(VIEWS)}")
        if dim != 3:
            raise OutputError("views apply to 3D runs only")
    first = _read_frame(frames[chosen[0]])
    parts, x0 = _parts(first, frames[chosen[0]], dim)  # the topology, from the first frame shown only
    shown_parts = [p for p in parts if not (hide_obstacles and p.kind == "obstacle")]
    if not shown_parts:
        raise OutputError(f"{run_dir}: nothing left to draw without the obstacles")
    xs = [(chosen[0], x0)]
    for k in chosen[1:]:
        mesh = first if k == chosen[0] else _read_frame(frames[k])
        if len(mesh.points) != len(first.points) or _cell_counts(mesh) != _cell_counts(first):
            raise OutputError(f"{frames[k]}: its mesh differs from step {chosen[0]}'s (a remesh between them?)")
        xs.append((k, np.asarray(mesh.points, dtype=np.float64)[:, :dim]))
    out = Path(out_png)
    if views:
        k, x = xs[-1]
        panels = [(f"step {k}, {v}", x) for v in views]
        width, height = size or (500 * len(panels), 500)
        render_frames_png(out, shown_parts, panels, dim=3, up=up, views=[VIEWS[v] for v in views], size=(width, height))
    else:
        panels = [(f"step {k}", x) for k, x in xs]
        width, height = size or (max(600, 400 * len(panels)), 500 if dim == 3 else 400)
        render_frames_png(out, shown_parts, panels, dim=dim, up=up, size=(width, height))
    return out
