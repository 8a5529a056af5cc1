"""Plain mesh containers shared by every layer."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class VolumeMesh:
    """A simplicial solid: tetrahedra in 3D (elements (m,4)) or triangles in 2D (elements (m,3)).

    ``vertices`` is (n, d) float64, ``elements`` is (m, d+1) int64, positively oriented
    (positive signed volume / area).
    """

    vertices: np.ndarray
    elements: np.ndarray
    source: str = "<array>"
    #: named vertex groups read from the file (point sets, or integer/bool point fields: nonzero = member)
    point_groups: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1])

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_elements(self) -> int:
        return int(self.elements.shape[0])


@dataclass
class SurfaceMesh:
    """A triangle surface in 3D (faces (m,3)) or a polyline boundary in 2D (faces (m,2)).

    ``vertices`` is (n, d) float64, ``faces`` is (m, k) int64, outward oriented when closed.
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: str = "<array>"
    extra: dict = field(default_factory=dict)

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1])

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])
