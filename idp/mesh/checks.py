"""``idp check MESH...``: read a mesh without raising and report everything wrong with it.

The report lists orientation (inverted / degenerate elements), the boundary surface's
topology (closed, manifold, consistently oriented) and self-intersections, each problem as
a sentence naming the first offending indices, so a user can fix the file before a run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from idp.contact.intersections import surface_intersecting_pairs
from idp.errors import MeshError
from idp.mesh.io import read_mesh
from idp.mesh.quality import signed_volumes
from idp.mesh.surface import SurfaceTopology, boundary_faces, enclosed_volume, surface_topology
from idp.mesh.types import SurfaceMesh, VolumeMesh

_LISTED = 10


def _indices(idx: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in idx[:_LISTED])
    return shown + (", ..." if idx.size > _LISTED else "")


@dataclass
class MeshReport:
    """What ``check_mesh`` found in one file; ``ok`` is False when ``problems`` is non-empty."""

    path: str
    kind: str  # "volume", "surface" or "unreadable"
    dim: int = 0
    num_vertices: int = 0
    num_elements: int | None = None  # volume meshes only
    num_faces: int = 0  # surface faces, or boundary faces of a volume mesh
    topology: SurfaceTopology | None = None
    num_inverted: int = 0
    num_degenerate: int = 0
    num_intersecting_pairs: int = 0
    enclosed_volume: float | None = None
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def format(self) -> str:
        """Multi-line human-readable report."""
        lines = [f"{self.path}: {'OK' if self.ok else 'PROBLEMS FOUND'}"]
        if self.kind == "unreadable":
            lines += [f"  problem: {p}" for p in self.problems]
            return "\n".join(lines)
        what = "faces" if self.kind == "surface" else "boundary faces"
        lines.append(f"  kind: {self.kind} ({self.dim}D), {self.num_vertices} vertices")
        if self.num_elements is not None:
            lines.append(
                f"  elements: {self.num_elements} (inverted {self.num_inverted}, degenerate {self.num_degenerate})"
            )
        else:
            lines.append(f"  degenerate faces: {self.num_degenerate}")
        t = self.topology
        if t is not None:
            unit = "vertices" if self.dim == 2 else "edges"
            lines.append(
                f"  {what}: {self.num_faces}, components {t.num_components}, "
                f"closed {'yes' if t.is_closed else 'no'}, "
                f"oriented {'yes' if t.is_consistently_oriented else 'no'} "
                f"(open {unit} {t.num_boundary_edges}, non-manifold {t.num_nonmanifold_edges}, "
                f"inconsistent {t.num_inconsistent_edges})"
            )
        if self.enclosed_volume is not None:
            lines.append(f"  enclosed {'area' if self.dim == 2 else 'volume'}: {self.enclosed_volume:.6g}")
        lines.append(f"  intersecting pairs: {self.num_intersecting_pairs}")
        lines += [f"  problem: {p}" for p in self.problems]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def _check_volume(mesh: VolumeMesh, rep: MeshReport) -> np.ndarray:
    """Orientation checks; returns the elements with every element made positive."""
    elems = mesh.elements.copy()
    vol = signed_volumes(mesh.vertices, elems)
    absvol = np.abs(vol)
    degenerate = absvol <= 1e-12 * float(absvol.mean())
    neg = np.flatnonzero((vol < 0) & ~degenerate)
    pos = np.flatnonzero((vol > 0) & ~degenerate)
    deg = np.flatnonzero(degenerate)
    rep.num_degenerate = int(deg.size)
    if deg.size:
        rep.problems.append(f"{deg.size} degenerate elements (zero or near-zero volume): {_indices(deg)}")
    if neg.size and pos.size:
        minority = neg if neg.size <= pos.size else pos
        rep.num_inverted = int(minority.size)
        rep.problems.append(
            f"mixed orientation: {minority.size} of {elems.shape[0]} elements are oriented "
            f"against the rest: {_indices(minority)}"
        )
    elif neg.size:
        rep.notes.append("all elements are negatively oriented; idp flips them when loading")
    elems[neg] = elems[neg][:, [1, 0, *range(2, elems.shape[1])]]
    return elems


def check_mesh(path: str | os.PathLike) -> MeshReport:
    """Read ``path`` without raising on bad elements and report what is wrong with it.

    Unreadable files (missing, bad format, NaN coordinates, bad indices) give a report of
    kind "unreadable" carrying the error message.
    """
    p = str(Path(path))
    try:
        mesh = read_mesh(p, fix_orientation=False, validate=False)
    except MeshError as exc:
        return MeshReport(path=p, kind="unreadable", problems=[str(exc)])

    if isinstance(mesh, VolumeMesh):
        rep = MeshReport(
            path=p, kind="volume", dim=mesh.dim, num_vertices=mesh.num_vertices, num_elements=mesh.num_elements
        )
        faces = boundary_faces(_check_volume(mesh, rep))
    else:
        assert isinstance(mesh, SurfaceMesh)
        rep = MeshReport(path=p, kind="surface", dim=mesh.dim, num_vertices=mesh.num_vertices)
        faces = mesh.faces
        if faces.shape[1] == 3:
            v = mesh.vertices
            area2 = np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1)
            deg = np.flatnonzero(area2 <= 1e-12 * float(area2.mean()))
            rep.num_degenerate = int(deg.size)
            if deg.size:
                rep.problems.append(f"{deg.size} degenerate faces (zero area): {_indices(deg)}")

    rep.num_faces = int(faces.shape[0])
    topo = surface_topology(faces, mesh.num_vertices)
    rep.topology = topo
    unit = "vertices" if faces.shape[1] == 2 else "edges"
    if topo.num_nonmanifold_edges:
        rep.problems.append(f"{topo.num_nonmanifold_edges} non-manifold {unit} (shared by more than two faces)")
    if topo.num_inconsistent_edges:
        rep.problems.append(f"{topo.num_inconsistent_edges} {unit} where neighbouring faces have opposite orientation")
    if topo.num_boundary_edges:
        rep.notes.append(f"open surface: {topo.num_boundary_edges} boundary {unit}")
    if topo.is_closed and topo.is_consistently_oriented:
        vol = enclosed_volume(mesh.vertices, faces)
        rep.enclosed_volume = vol
        if isinstance(mesh, SurfaceMesh) and vol < 0:
            rep.notes.append("surface is oriented inward (negative enclosed volume)")

    pairs = surface_intersecting_pairs(mesh.vertices, faces)
    rep.num_intersecting_pairs = int(pairs.shape[0])
    if pairs.shape[0]:
        first = ", ".join(f"({int(a)}, {int(b)})" for a, b in pairs[:_LISTED])
        what = "segment-segment" if faces.shape[1] == 2 else "edge-triangle"
        rep.problems.append(
            f"{pairs.shape[0]} intersecting {what} pairs on the "
            f"{'boundary' if rep.kind == 'volume' else 'surface'}: {first}"
            + (", ..." if pairs.shape[0] > _LISTED else "")
        )
    return rep
