"""Per-element signed volumes, the inverted / degenerate element queries built on them, and tet shape quality.

Every layer that needs orientation (file loading, checks, the injectivity certificate) goes
through :func:`signed_volumes`, so the sign convention lives in one place: a tetrahedron
``(a, b, c, d)`` is positive when ``det[b-a, c-a, d-a] > 0`` and a triangle ``(a, b, c)`` in
2D is positive when it is counter-clockwise.

Shape quality (:func:`dihedral_angles`, :func:`radius_ratios`, :func:`mesh_quality`) is what
remeshing reports before and after, so a caller can see whether re-tetrahedralising helped.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from idp.errors import MeshError


def _check_simplices(vertices: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (vertices float64, elements int64) after checking that they describe simplices."""
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(elements)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise MeshError(f"vertices must be an (n, 2) or (n, 3) array, got shape {v.shape}")
    d = v.shape[1]
    if e.ndim != 2 or e.shape[1] != d + 1:
        raise MeshError(f"elements must be an (m, {d + 1}) array for {d}D vertices, got shape {e.shape}")
    return v, e.astype(np.int64, copy=False)


def signed_volumes(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron (``det/6``) or signed area of each 2D triangle (``det/2``)."""
    v, e = _check_simplices(vertices, elements)
    if e.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    x0 = v[e[:, 0]]
    if v.shape[1] == 3:
        a = v[e[:, 1]] - x0
        b = v[e[:, 2]] - x0
        c = v[e[:, 3]] - x0
        return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    a = v[e[:, 1]] - x0
    b = v[e[:, 2]] - x0
    return (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) / 2.0


def inverted_elements(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Indices (int64) of elements whose signed volume is <= 0."""
    return np.flatnonzero(signed_volumes(vertices, elements) <= 0.0).astype(np.int64)


def degenerate_elements(vertices: np.ndarray, elements: np.ndarray, rel_tol: float = 1e-12) -> np.ndarray:
    """Indices (int64) of elements with ``|volume| <= rel_tol * mean |volume|``.

    The threshold is relative so the test does not depend on the mesh's units. When every
    element has zero volume, all of them are degenerate.
    """
    vol = np.abs(signed_volumes(vertices, elements))
    if vol.size == 0:
        return np.zeros(0, dtype=np.int64)
    threshold = rel_tol * float(vol.mean())
    return np.flatnonzero(vol <= threshold).astype(np.int64)


# Face i of a tet is the one opposite vertex i (outward for a positive tet, as in idp.mesh.surface).
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)
# Edges (0,1), (0,2), (0,3), (1,2), (1,3), (2,3) and, per edge, the two faces that share it
# (the faces opposite the two vertices not on the edge).
_EDGE_FACE_PAIRS = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]], dtype=np.int64)


def _tets(vertices: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v, e = _check_simplices(vertices, elements)
    if v.shape[1] != 3:
        raise MeshError(f"tet quality needs (n, 3) vertices and (m, 4) elements, got {v.shape} and {e.shape}")
    return v, e


def _face_area_vectors(v: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(m, 4, 3) area vectors (normal times area) of the faces opposite each vertex."""
    f = v[e[:, _TET_FACES]]  # (m, 4, 3 corners, 3 coords)
    return 0.5 * np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])


def dihedral_angles(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(m, 6) interior dihedral angles in degrees at the edges (0,1), (0,2), (0,3), (1,2), (1,3), (2,3).

    Independent of orientation (inverted tets give the same angles). A regular tet has all six
    equal to arccos(1/3) ≈ 70.53°; a flat sliver has angles near 0° and 180°. An angle at a
    face of zero area is undefined and reported as 0.
    """
    v, e = _tets(vertices, elements)
    if e.shape[0] == 0:
        return np.zeros((0, 6), dtype=np.float64)
    n = _face_area_vectors(v, e)
    a = n[:, _EDGE_FACE_PAIRS[:, 0]]
    b = n[:, _EDGE_FACE_PAIRS[:, 1]]
    norms = np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2)
    dots = np.einsum("mkj,mkj->mk", a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        # the interior angle is pi minus the angle between the two outward normals
        cos = np.where(norms > 0, -dots / np.where(norms > 0, norms, 1.0), 1.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def radius_ratios(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(m,) normalised radius ratio 3·inradius/circumradius: 1 for a regular tet, 0 for a flat one.

    Uses r = 3|V| / (total face area) and R = |a|²(b×c) + |b|²(c×a) + |c|²(a×b) / (12|V|) with
    a, b, c the edges from vertex 0, so ratio = 108 V² / (area · |…|). Orientation-independent.
    """
    v, e = _tets(vertices, elements)
    if e.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    x0 = v[e[:, 0]]
    a, b, c = v[e[:, 1]] - x0, v[e[:, 2]] - x0, v[e[:, 3]] - x0
    bc, ca, ab = np.cross(b, c), np.cross(c, a), np.cross(a, b)
    vol = np.einsum("ij,ij->i", a, bc) / 6.0
    area = np.linalg.norm(_face_area_vectors(v, e), axis=2).sum(axis=1)
    circ = np.linalg.norm(
        np.einsum("i,ij->ij", np.einsum("ij,ij->i", a, a), bc)
        + np.einsum("i,ij->ij", np.einsum("ij,ij->i", b, b), ca)
        + np.einsum("i,ij->ij", np.einsum("ij,ij->i", c, c), ab),
        axis=1,
    )
    denom = area * circ
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(denom > 0, 108.0 * vol * vol / np.where(denom > 0, denom, 1.0), 0.0)
    return np.clip(ratio, 0.0, 1.0)


@dataclass(frozen=True)
class MeshQuality:
    """Shape summary of a tet mesh: worst dihedral angles (degrees) and radius ratios (1 = regular)."""

    min_dihedral: float
    max_dihedral: float
    mean_radius_ratio: float
    min_radius_ratio: float
    num_elements: int

    def to_dict(self) -> dict[str, float | int]:
        """Plain dict for JSON reports."""
        return asdict(self)


def mesh_quality(vertices: np.ndarray, elements: np.ndarray) -> MeshQuality:
    """:class:`MeshQuality` of a tet mesh (an empty mesh reports NaN angles and ratios)."""
    angles = dihedral_angles(vertices, elements)
    ratios = radius_ratios(vertices, elements)
    if ratios.size == 0:
        nan = float("nan")
        return MeshQuality(nan, nan, nan, nan, 0)
    return MeshQuality(
        min_dihedral=float(angles.min()),
        max_dihedral=float(angles.max()),
        mean_radius_ratio=float(ratios.mean()),
        min_radius_ratio=float(ratios.min()),
        num_elements=int(ratios.size),
    )
