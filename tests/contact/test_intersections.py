"""Edge-triangle and segment-segment intersection detection."""

import numpy as np

from idp.contact.intersections import (
    count_intersections,
    find_intersecting_pairs,
    find_intersecting_segments,
    intersecting_pair_keys,
)
from idp.mesh.generate import polygon_circle, tet_box
from idp.mesh.surface import boundary_faces, unique_edges

TRI = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def _box_surface(shift):
    m = tet_box(resolution=3)
    return m.vertices + shift, boundary_faces(m.elements), m.num_vertices


def test_single_edge_piercing_triangle():
    v = np.vstack([TRI, [[0.2, 0.2, -1.0], [0.2, 0.2, 1.0], [5, 5, -1], [5, 5, 1]]])
    edges = np.array([[3, 4], [5, 6], [0, 1]])  # piercing, far away, shares vertices
    pairs = find_intersecting_pairs(v, edges, np.array([[0, 1, 2]]))
    assert pairs.tolist() == [[0, 0]] and pairs.dtype == np.int64


def test_edge_above_triangle_or_coplanar_outside_is_not_reported():
    v = np.vstack([TRI, [[0.2, 0.2, 0.1], [0.2, 0.2, 1.0], [0.6, 0.6, 0.0], [1.0, 1.0, 0.0]]])
    edges = np.array([[3, 4], [5, 6]])
    assert find_intersecting_pairs(v, edges, np.array([[0, 1, 2]])).shape == (0, 2)


def test_coplanar_crossing_edge_is_reported():
    v = np.vstack([TRI, [[-1.0, 0.2, 0.0], [3.0, 0.2, 0.0]]])
    pairs = find_intersecting_pairs(v, np.array([[3, 4]]), np.array([[0, 1, 2]]))
    assert pairs.tolist() == [[0, 0]]


def test_overlapping_boxes_intersect_and_separated_do_not():
    va, fa, n = _box_surface(np.zeros(3))
    for shift, expect_hits in ((np.array([0.7, 0.3, 0.2]), True), (np.array([2.5, 0.0, 0.0]), False)):
        vb, fb, _ = _box_surface(shift)
        v = np.vstack([va, vb])
        f = np.vstack([fa, fb + n])
        pairs = find_intersecting_pairs(v, unique_edges(f), f)
        assert (pairs.shape[0] > 0) == expect_hits
    # a single closed box never intersects itself (shared-vertex pairs are excluded)
    assert count_intersections(va, fa) == 0


def test_2d_segments():
    v = np.array([[0.0, 0], [1, 1], [0, 1], [1, 0], [2, 0], [3, 0], [2.5, 0], [4, 0]])
    segs = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [3, 4]])
    # 0x1 cross; 2 and 3 overlap collinearly; 4 shares vertices with 1, 2; 2-4 share vertex 4
    assert find_intersecting_segments(v, segs).tolist() == [[0, 1], [2, 3]]


def test_2d_circles():
    a = polygon_circle(1.0, segments=40)
    for dx, hits in ((1.0, 2), (2.5, 0)):
        v = np.vstack([a.vertices, a.vertices + np.array([dx, 0.0])])
        f = np.vstack([a.faces, a.faces + 40])
        assert count_intersections(v, f) == hits
    # a long segment through many short ones is still found (long-segment path)
    v = np.vstack([a.vertices, [[-2.0, 0.05], [2.0, 0.05]]])
    f = np.vstack([a.faces, [[40, 41]]])
    assert count_intersections(v, f) == 2


def test_pair_keys_memo_answers_only_the_same_input():
    """intersecting_pair_keys remembers its last answers by a digest of the input: the same vertices again give the
    same keys (a copy: changing it changes nothing remembered), moved vertices are computed afresh."""
    va, fa, n = _box_surface(np.zeros(3))
    vb, fb, _ = _box_surface(np.array([0.7, 0.3, 0.2]))
    v, f = np.vstack([va, vb]), np.vstack([fa, fb + n])
    first = intersecting_pair_keys(v, f)
    assert first and intersecting_pair_keys(v.copy(), f.copy()) == first
    first.clear()
    assert intersecting_pair_keys(v, f)  # the memo kept its own copy
    apart = v.copy()
    apart[n:] += np.array([3.0, 0.0, 0.0])
    assert intersecting_pair_keys(apart, f) == set()
    assert intersecting_pair_keys(v, f) == intersecting_pair_keys(v[:, [0, 1, 2]].copy(order="F"), f)
