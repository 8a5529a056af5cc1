"""Edge-triangle and segment-segment intersection detection."""

import numpy as np
import pytest

from idp.contact.intersections import (
    _grid,
    _undecided_edge_face_pairs,
    count_intersections,
    find_intersecting_pairs,
    find_intersecting_segments,
    has_intersections,
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


def _brute_box_pairs(v, e, f):
    """Every (edge, face) pair with overlapping closed boxes and no shared vertex, by testing all pairs."""
    elo, ehi = v[e].min(axis=1), v[e].max(axis=1)
    flo, fhi = v[f].min(axis=1), v[f].max(axis=1)
    overlap = np.all((elo[:, None] <= fhi[None]) & (ehi[:, None] >= flo[None]), axis=2)
    shares = (e[:, None, :, None] == f[None, :, None, :]).any(axis=(2, 3))
    i, j = np.nonzero(overlap & ~shares)
    return set(zip(i.tolist(), j.tolist(), strict=True))


@pytest.mark.parametrize("seed", range(12))
def test_grid_broad_phase_finds_every_overlapping_pair_once(seed):
    """The certificate's own broad phase against all pairs: random soups, lattice points (boxes that touch exactly,
    flat boxes, coplanar triangles) and fans of long spokes among small triangles (boxes over many cells)."""
    rng = np.random.default_rng(seed)
    kind = seed % 3
    if kind == 0:
        v = rng.normal(size=(200, 3)) * rng.uniform(0.1, 3.0, size=3)
    elif kind == 1:
        v = rng.integers(0, 5, size=(150, 3)).astype(float) * rng.uniform(0.5, 2.0)
        v[rng.random(150) < 0.5, 2] = 0.0
    else:
        v = rng.uniform(-0.05, 0.05, size=(200, 3))
        v[:12] = rng.uniform(-5.0, 5.0, size=(12, 3))  # far-flung hubs: long edges through the whole grid
    f = rng.integers(0, v.shape[0], size=(180, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    e = unique_edges(f)
    v, f = np.ascontiguousarray(v), np.ascontiguousarray(f, dtype=np.int64)
    origin, h, dims, lo, hi = _grid(v, e, f)
    out = np.empty((e.shape[0] * f.shape[0], 2), np.int64)
    # an infinite scale leaves the float filter unsure of every pair: the kernel then lists its whole broad phase
    n = _undecided_edge_face_pairs(v, e, f, origin, h, dims, lo, hi, np.inf, out)
    got = [tuple(p) for p in out[:n].tolist()]
    assert len(got) == len(set(got))  # each pair once
    assert set(got) == _brute_box_pairs(v, e, f)


def test_crossing_pairs_equal_the_robust_predicate_on_every_pair():
    """find_intersecting_pairs (grid, float filter, robust predicate on the rest) against ipctk's predicate on all
    pairs of a lattice soup full of exact touching and coplanar cases."""
    import ipctk

    rng = np.random.default_rng(4)
    v = rng.integers(0, 4, size=(60, 3)).astype(float)
    v[:30, 2] = 0.0
    f = rng.integers(0, 60, size=(70, 3))
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    f = f[area > 0]  # ipctk's predicate calls an edge near a zero-area triangle intersecting (the filter does not)
    e = unique_edges(f)
    expected = [
        [i, j]
        for i in range(len(e))
        for j in range(len(f))
        if not set(e[i]) & set(f[j]) and ipctk.is_edge_intersecting_triangle(*v[e[i]], *v[f[j]])
    ]
    got = find_intersecting_pairs(v, e, f).tolist()
    assert got == expected and len(expected) > 10
    assert has_intersections(v, e, f)


@pytest.mark.parametrize("seed", range(6))
def test_has_intersections_answers_as_the_pairs_and_as_ipctk(seed):
    """has_intersections (the certificate's 3D test) says yes exactly when find_intersecting_pairs finds a pair, and
    agrees with ipctk's has_intersections, on two boxes moved through touching, crossing and apart."""
    import ipctk

    rng = np.random.default_rng(seed)
    va, fa, n = _box_surface(np.zeros(3))
    gap = (1.0, 2.0, 2.0 + 1e-9, 2.4)[seed % 4]  # the boxes span [-1, 1]: crossing, touching, just apart, apart
    shift = np.array([gap, 0.0, 0.0]) + rng.uniform(-0.1, 0.1, 3) * (seed >= 4)
    vb, fb, _ = _box_surface(shift)
    v, f = np.vstack([va, vb]), np.vstack([fa, fb + n])
    e = unique_edges(f)
    mesh = ipctk.CollisionMesh(v, e, f)
    expected = bool(ipctk.has_intersections(mesh, v, ipctk.LBVH()))
    assert has_intersections(v, e, f) == (len(find_intersecting_pairs(v, e, f)) > 0) == expected
    if seed in (0, 3):  # (a test that both answers occur)
        assert expected == (seed == 0)
