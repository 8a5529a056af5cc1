"""The certificate's reported minimum distance (compiled broad phase + exact distances) against ipctk's."""

from __future__ import annotations

import math

import ipctk
import numpy as np

from idp.contact.certificate import Certifier

_TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _two_tets(gap: float, tilt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two unit tetrahedra, the second shifted by 1 + gap along x and rotated by ``tilt`` about x."""
    a = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    c, s = math.cos(tilt), math.sin(tilt)
    rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    b = (a - [1.0, 0, 0]) * -1.0 @ rot.T + [1.0 + gap, 0.0, 0.0]  # mirrored: vertex 1 faces the first tet
    x = np.vstack([a, b])
    faces = np.vstack([_TET_FACES, _TET_FACES[:, ::-1] + 4])
    tets = np.array([[0, 1, 2, 3], [4, 6, 5, 7]])
    return x, faces, tets


def _ipctk_min_distance(x: np.ndarray, faces: np.ndarray, dq: float) -> float:
    mesh = ipctk.CollisionMesh.build_from_full_mesh(x, ipctk.edges(faces.astype(np.int32)), faces.astype(np.int32))
    vs = x[np.asarray(mesh.to_full_vertex_id())]
    c = ipctk.NormalCollisions()
    c.build(mesh, vs, dq, 0.0, ipctk.LBVH())
    return math.sqrt(max(c.compute_minimum_distance(mesh, vs), 0.0)) if len(c) else math.inf


def test_min_distance_matches_ipctk() -> None:
    for gap, tilt in [(1e-3, 0.0), (2e-3, 0.3), (5e-4, 1.1), (0.5, 0.2)]:
        x, faces, tets = _two_tets(gap, tilt)
        cert = Certifier(x, faces, [tets], distance_query=1e-2).check(x)
        assert cert.ok
        expected = _ipctk_min_distance(x, faces, 1e-2)
        if math.isinf(expected):
            assert math.isinf(cert.min_distance)
        else:
            assert abs(cert.min_distance - expected) <= 1e-12
