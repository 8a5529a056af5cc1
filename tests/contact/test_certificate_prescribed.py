"""The certificate with a prescribed group (pairs among its vertices left out of contact): crossings among the
group's vertices only are counted and pass, any crossing with a vertex outside it fails, and the group's own pairs
stay out of the reported minimum distance."""

from __future__ import annotations

import math

import numpy as np

from idp.contact.certificate import Certifier
from idp.mesh.generate import ellipsoid_surface


def _three_spheres(overlap_ab: float, gap_bc: float) -> tuple[np.ndarray, np.ndarray]:
    """Spheres a, b, c of radius 0.3 on the x axis: a and b overlap by ``overlap_ab``, c is ``gap_bc`` from b."""
    s = ellipsoid_surface((0.3, 0.3, 0.3), subdivisions=2)
    n = s.vertices.shape[0]
    centres = [0.0, 0.6 - overlap_ab, 1.2 - overlap_ab + gap_bc]
    # skewed along y: no two spheres' vertices meet exactly
    x = np.vstack([s.vertices + np.array([c, 0.01 * k, 0.0]) for k, c in enumerate(centres)])
    faces = np.vstack([s.faces + k * n for k in range(3)])
    return x, faces


def _group(x: np.ndarray, spheres: tuple[int, ...]) -> np.ndarray:
    n = x.shape[0] // 3
    g = np.zeros(x.shape[0], dtype=bool)
    for k in spheres:
        g[k * n : (k + 1) * n] = True
    return g


def test_crossings_among_the_prescribed_group_are_counted_not_failed() -> None:
    x, faces = _three_spheres(overlap_ab=0.05, gap_bc=0.02)
    plain = Certifier(x, faces, [], distance_query=0.05).check(x)
    assert not plain.ok  # a and b cross
    cert = Certifier(x, faces, [], distance_query=0.05, prescribed_vertices=_group(x, (0, 1))).check(x)
    assert cert.ok and cert.prescribed_crossing_pairs > 0
    assert "prescribed" in cert.describe()
    # the group's own (crossing) pairs are out of the minimum distance: what is left is b to c, about the gap
    assert 0.015 < cert.min_distance < 0.025


def test_a_crossing_with_a_vertex_outside_the_group_fails() -> None:
    x, faces = _three_spheres(overlap_ab=0.05, gap_bc=-0.03)  # b and c cross too
    cert = Certifier(x, faces, [], distance_query=0.05, prescribed_vertices=_group(x, (0, 1))).check(x)
    assert not cert.ok and not cert.intersection_free
    clean, faces = _three_spheres(overlap_ab=-0.02, gap_bc=0.02)  # nothing crosses
    cert = Certifier(clean, faces, [], distance_query=0.05, prescribed_vertices=_group(clean, (0, 1))).check(clean)
    assert cert.ok and cert.prescribed_crossing_pairs == 0 and math.isfinite(cert.min_distance)
