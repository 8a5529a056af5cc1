"""Scene objects as seen by the output layer: named vertex subsets of the global simulation state."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PART_KINDS = ("deformable", "shell", "obstacle")


@dataclass
class Part:
    """One object of a scene, in the global vertex numbering of the simulation."""

    name: str
    kind: str  # "deformable" | "shell" (a deforming triangle surface in 3D) | "obstacle"
    vertex_ids: np.ndarray  # (k,) int64 global ids of this part's vertices (contiguous range in practice)
    elements: np.ndarray | None  # (m, d+1) int64 GLOBAL ids: tets (3D) / triangles (2D); None for shells, obstacles
    surface: np.ndarray  # (f, d) int64 GLOBAL ids: outward boundary triangles (3D) or segments (2D)

    def __post_init__(self) -> None:
        if self.kind not in PART_KINDS:
            raise ValueError(f"part {self.name!r}: kind must be one of {PART_KINDS}, got {self.kind!r}")
        self.vertex_ids = np.asarray(self.vertex_ids, dtype=np.int64).reshape(-1)
        self.surface = np.asarray(self.surface, dtype=np.int64)
        if self.elements is not None:
            self.elements = np.asarray(self.elements, dtype=np.int64)


def check_parts(parts: list[Part], dim: int, num_vertices: int | None = None) -> int:
    """Validate ``parts`` for dimension ``dim``; return the smallest admissible vertex count.

    Raises ``ValueError`` naming the part and field when a shape or an index is wrong.
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    need = 0
    for p in parts:
        if p.surface.ndim != 2 or p.surface.shape[1] != dim:
            raise ValueError(f"part {p.name!r}: surface must be (f, {dim}), got {p.surface.shape}")
        arrays = [("vertex_ids", p.vertex_ids), ("surface", p.surface)]
        if p.kind == "deformable":
            if p.elements is None:
                raise ValueError(f"part {p.name!r}: a deformable part needs elements")
            if p.elements.ndim != 2 or p.elements.shape[1] != dim + 1:
                raise ValueError(f"part {p.name!r}: elements must be (m, {dim + 1}), got {p.elements.shape}")
            arrays.append(("elements", p.elements))
        for field_name, arr in arrays:
            if arr.size == 0:
                continue
            lo, hi = int(arr.min()), int(arr.max())
            if lo < 0:
                raise ValueError(f"part {p.name!r}: {field_name} has negative vertex id {lo}")
            if num_vertices is not None and hi >= num_vertices:
                raise ValueError(
                    f"part {p.name!r}: {field_name} refers to vertex {hi} but there are {num_vertices} vertices"
                )
            need = max(need, hi + 1)
    return need
