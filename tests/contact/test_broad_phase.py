"""The numba surface broad phase: exact agreement with a brute-force box test (and, for sweeps, the moving-box
test), on short sweeps and on long ones (the split into long and short primitives), completeness against ipctk's
collision set and against true distances along the sweep, and the exclusions (shared vertices, all-static pairs)."""

import itertools

import ipctk
import numba
import numpy as np
import pytest

import idp.contact._broad_phase as _bp
from idp.contact._broad_phase import surface_candidates
from idp.mesh.generate import box_surface, tet_ball
from idp.mesh.surface import boundary_faces

# ----------------------------------------------------------------------------- scenes


def _ball_surface(radius, center, resolution):
    vol = tet_ball(radius, center, resolution)
    faces = boundary_faces(vol.elements)
    used = np.unique(faces)
    remap = np.full(vol.num_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return vol.vertices[used], remap[faces]


def _join(parts, num_dynamic_parts):
    """Concatenate (vertices, faces) parts; the first num_dynamic_parts are dynamic (their vertices first)."""
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    V = np.vstack(verts).astype(np.float64)
    F = np.vstack(faces).astype(np.int32)
    nd = sum(len(v) for v, _ in parts[:num_dynamic_parts])
    return V, ipctk.edges(F).astype(np.int32), F, nd


def two_boxes(gap=1e-3, jitter=1e-4, seed=0):
    """Two dynamic boxes stacked along z, a gap below dhat between them."""
    a = box_surface((0, 0, 0), (1, 1, 1), 3)
    b = box_surface((0.3, 0.2, 1 + gap), (1.3, 1.2, 2 + gap), 3)
    V, E, F, nd = _join([(a.vertices, a.faces), (b.vertices, b.faces)], 2)
    V += jitter * np.random.default_rng(seed).uniform(-1, 1, V.shape)
    return V, E, F, nd


def ball_in_box(radius=0.985, seed=1):
    """A dynamic ball surface almost touching the walls of a closed static box (coarser triangles)."""
    bv, bf = _ball_surface(radius, (0.0, 0.011, -0.002), 3)
    box = box_surface((-1, -1, -1), (1, 1, 1), 3)
    V, E, F, nd = _join([(bv, bf), (box.vertices, box.faces)], 1)
    V[:nd] += 2e-3 * np.random.default_rng(seed).uniform(-1, 1, (nd, 3))
    return V, E, F, nd


def rounded_cube_in_box(seed=4):
    """A dynamic rounded cube (superellipsoid) whose flat sides lie 2.5e-3 from a static box's walls."""
    bv, bf = _ball_surface(1.0, (0, 0, 0), 3)
    u = bv / np.linalg.norm(bv, axis=1, keepdims=True)
    s = np.sign(u) * np.abs(u) ** 0.25  # |x|^8 + |y|^8 + |z|^8 = 1 after the normalisation below
    s /= ((s**8).sum(axis=1, keepdims=True)) ** 0.125
    s = s * (1 - 2.5e-3) + 1e-3 * np.random.default_rng(seed).uniform(-1, 1, s.shape)
    box = box_surface((-1, -1, -1), (1, 1, 1), 3)
    return _join([(s, bf), (box.vertices, box.faces)], 1)


def ball_in_big_triangles(seed=2):
    """A small dynamic ball inside a static cage of 12 triangles much larger than the ball's."""
    bv, bf = _ball_surface(0.3, (0.6, 0.0, 0.0), 3)
    cage = box_surface((-0.95, -1, -1), (0.903, 1, 1), 1)
    V, E, F, nd = _join([(bv, bf), (cage.vertices, cage.faces)], 1)
    V[:nd] += 1e-3 * np.random.default_rng(seed).uniform(-1, 1, (nd, 3))
    return V, E, F, nd


def triangle_soup(seed=3, nv=70, nf=60, nd=45):
    """Random triangles of all sizes and orientations; edges with one static and one dynamic vertex."""
    rng = np.random.default_rng(seed)
    V = rng.uniform(0, 1, (nv, 3))
    F = np.array([rng.choice(nv, 3, replace=False) for _ in range(nf)], dtype=np.int32)
    return V, ipctk.edges(F).astype(np.int32), F, nd


SCENES = {
    "two_boxes": two_boxes,
    "ball_in_box": ball_in_box,
    "ball_in_big_triangles": ball_in_big_triangles,
    "rounded_cube_in_box": rounded_cube_in_box,
    "triangle_soup": triangle_soup,
}


# ----------------------------------------------------------------------------- reference


def _boxes(V0, V1, prims):
    lo, hi = V0[prims].min(axis=1), V0[prims].max(axis=1)
    if V1 is not None:
        lo = np.minimum(lo, V1[prims].min(axis=1))
        hi = np.maximum(hi, V1[prims].max(axis=1))
    return lo, hi


def _moving_meet(V0, V1, pa, pb, infl, pad):
    """Per pair (rows of pa, pb: vertex ids of the two primitives) whether their moving boxes
    [lo0 + t dmin, hi0 + t dmax] come within infl + pad of each other on every axis at one t in [0, 1]."""
    D = V1 - V0
    lo_a, hi_a, dn_a, dx_a = V0[pa].min(1), V0[pa].max(1), D[pa].min(1), D[pa].max(1)
    lo_b, hi_b, dn_b, dx_b = V0[pb].min(1), V0[pb].max(1), D[pb].min(1), D[pb].max(1)
    tlo, thi = np.zeros(len(pa)), np.ones(len(pa))
    ok = np.ones(len(pa), dtype=bool)
    for c, r in ((dn_a - dx_b, hi_b + infl - lo_a + pad), (dn_b - dx_a, hi_a + infl - lo_b + pad)):
        with np.errstate(divide="ignore", invalid="ignore"):
            q = r / c
        thi = np.minimum(thi, np.where(c > 0, q, np.inf).min(1))
        tlo = np.maximum(tlo, np.where(c < 0, q, -np.inf).max(1))
        ok &= ~((c == 0) & (r < 0)).any(1)
    return ok & (tlo <= thi)


def brute_force(V0, V1, E, F, infl, nd, pad=0.0, moving=True):
    """Every pair passing lo_a <= hi_b + infl and lo_b <= hi_a + infl on all axes, minus the exclusions; for a sweep
    (V1 given) also passing the moving-box test with margin ``pad`` unless not ``moving``."""
    vlo, vhi = _boxes(V0, V1, np.arange(len(V0))[:, None])
    elo, ehi = _boxes(V0, V1, E)
    flo, fhi = _boxes(V0, V1, F)
    ok = ((flo[:, None] <= vhi[None] + infl) & (vlo[None] <= fhi[:, None] + infl)).all(axis=-1)
    f, v = np.nonzero(ok)
    keep = (F[f] != v[:, None]).all(axis=1) & ((F[f].min(axis=1) < nd) | (v < nd))
    if V1 is not None and moving:
        keep &= _moving_meet(V0, V1, F[f], v[:, None], infl, pad)
    fv = set(zip(f[keep].tolist(), v[keep].tolist(), strict=True))
    ok = ((elo[:, None] <= ehi[None] + infl) & (elo[None] <= ehi[:, None] + infl)).all(axis=-1)
    a, b = np.nonzero(np.triu(ok, 1))
    share = (E[a][:, :, None] == E[b][:, None, :]).any(axis=(1, 2))
    keep = ~share & ((E[a].min(axis=1) < nd) | (E[b].min(axis=1) < nd))
    if V1 is not None and moving:
        keep &= _moving_meet(V0, V1, E[a], E[b], infl, pad)
    ee = set(zip(a[keep].tolist(), b[keep].tolist(), strict=True))
    return fv, ee


def sweep_end(V, nd, kind, seed):
    """End positions of a query: None (static), a short jitter of the dynamic vertices ("sweep"), or a long move
    ("long_sweep": the dynamic vertices turned 60 degrees about a vertical axis at one side of them, plus the jitter,
    so they move from not at all to across the scene and the broad phase splits long from short primitives)."""
    if kind == "static":
        return None
    rng = np.random.default_rng(seed)
    dyn = np.arange(len(V))[:, None] < nd
    V1 = V + np.where(dyn, 3e-3 * rng.standard_normal(V.shape), 0.0)
    if kind == "long_sweep":
        axis_at = V[:nd].min(axis=0)
        c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        V1 = np.where(dyn, (V1 - axis_at) @ R.T + axis_at, V1)
    return V1


def _bounds(V0, V1, E, F, infl, nd):
    """(pairs any query must report, pairs it may report): for a static query both the box-test set; for a sweep
    the moving-box set, and the swept-box set widened by the rounding margin (whether a sweep takes the moving-box
    test depends on how far it moves against the cell size of the query's primitives)."""
    if V1 is None:
        exact = brute_force(V0, None, E, F, infl, nd)
        return exact, exact
    return brute_force(V0, V1, E, F, infl, nd), brute_force(
        V0, V1, E, F, infl, nd, _scale_pad(V0, V1, infl), moving=False
    )


def _scale_pad(V0, V1, infl):
    """A margin above the broad phase's own (1e-9 of the coordinates' size): pairs within it may go either way."""
    return 1e-8 * (max(np.abs(V0).max(), np.abs(V1).max()) + infl)


def _as_sets(fv, ee):
    assert fv.dtype == np.int32 and ee.dtype == np.int32
    assert fv.ndim == 2 and fv.shape[1] == 2 and ee.ndim == 2 and ee.shape[1] == 2
    assert np.all(ee[:, 0] < ee[:, 1])
    sfv, see = set(map(tuple, fv.tolist())), set(map(tuple, ee.tolist()))
    assert len(sfv) == len(fv) and len(see) == len(ee), "duplicate pairs"
    return sfv, see


def _near_pairs_reported(V0, V1, E, F, infl, nd, got, label) -> int:
    """Asserts that every pair closer than ``infl`` at 11 sampled times of the sweep V0 -> V1 is in ``got`` (fv, ee
    sets); returns how many such pairs there were."""
    fv, ee = got
    met = 0
    for t in np.linspace(0.0, 1.0, 11):
        Vt = (1 - t) * V0 + t * V1
        near_fv, near_ee = brute_force(Vt, None, E, F, infl, nd)  # box-test superset; distances below
        for f, v in near_fv:
            if ipctk.point_triangle_distance(Vt[v], *Vt[F[f]]) < infl**2:
                assert (f, v) in fv, (label, t, f, v)
                met += 1
        for a, b in near_ee:
            if ipctk.edge_edge_distance(*Vt[E[a]], *Vt[E[b]]) < infl**2:
                assert (a, b) in ee, (label, t, a, b)
                met += 1
    return met


# ----------------------------------------------------------------------------- tests


SWEEPS = ["static", "sweep", "long_sweep"]


@pytest.mark.parametrize("sweep", SWEEPS)
@pytest.mark.parametrize("name", list(SCENES))
def test_matches_brute_force(name, sweep):
    """Static queries: exactly the box-test pairs. Sweeps: every pair passing the exact moving-box test and only
    swept-box pairs; a long sweep (which takes the moving-box test) only pairs passing that test within a hair's
    margin (its rounding margin)."""
    V, E, F, nd = SCENES[name]()
    V1 = sweep_end(V, nd, sweep, 7)
    for infl in (0.0, 1e-3, 2e-2):
        fv, ee = surface_candidates(V, V1, E, F, infl, nd)
        got = _as_sets(fv, ee)
        want = brute_force(V, V1, E, F, infl, nd)
        if V1 is None:
            assert got == want, (name, infl)
            continue
        wide = brute_force(V, V1, E, F, infl, nd, _scale_pad(V, V1, infl), moving=sweep == "long_sweep")
        assert want[0] <= got[0] <= wide[0], (name, infl, "fv")
        assert want[1] <= got[1] <= wide[1], (name, infl, "ee")
    assert len(want[0]) > 0 and len(want[1]) > 0


@pytest.mark.parametrize("name", list(SCENES))
def test_long_sweep_drops_pairs_that_never_meet_and_keeps_those_that_do(name):
    """On a long sweep the moving-box test drops swept-box pairs of primitives that never come near each other at
    the same time, and every pair that comes within the inflation at some sampled time of the sweep is reported."""
    V, E, F, nd = SCENES[name]()
    V1 = sweep_end(V, nd, "long_sweep", 8)
    infl = 2e-2
    fv, ee = _as_sets(*surface_candidates(V, V1, E, F, infl, nd))
    swept_fv, swept_ee = brute_force(V, V1, E, F, infl, nd, moving=False)
    assert fv <= swept_fv and ee <= swept_ee
    assert len(fv) + len(ee) < len(swept_fv) + len(swept_ee)
    assert _near_pairs_reported(V, V1, E, F, infl, nd, (fv, ee), name) > 0


def _query(V0, V1, E, F, infl, nd, long_reach):
    """The kernel itself with a chosen long-primitive threshold (inf: never split)."""
    still = np.zeros(len(V0), dtype=np.uint8)
    fv, ee, status = _bp._run(
        V0,
        V1,
        True,
        E,
        F,
        nd,
        still,
        infl,
        numba.get_num_threads(),
        _bp._CELL_SCALE,
        _bp._CELLS_PER_PRIM,
        _bp._CHUNKS_PER_THREAD,
        _bp._SPARE_ROWS,
        long_reach,
        _bp._LONG_SCALE,
        _bp._MOVING_REACH,
    )
    assert status == 0
    return _as_sets(fv, ee)


@pytest.mark.parametrize("name", list(SCENES))
def test_split_into_long_and_short_primitives_gives_the_unsplit_set(name):
    """The long/short split (long among long in a coarse grid, short among short in a fine one, the cross pass)
    reports exactly the pairs of one grid over every primitive, at several thresholds."""
    V, E, F, nd = SCENES[name]()
    V1 = sweep_end(V, nd, "long_sweep", 9)
    E, F = np.ascontiguousarray(E, dtype=np.int32), np.ascontiguousarray(F, dtype=np.int32)
    for infl in (1e-3, 2e-2):
        whole = _query(V, V1, E, F, infl, nd, np.inf)
        for reach in (0.25, 1.0, _bp._LONG_REACH):
            assert _query(V, V1, E, F, infl, nd, reach) == whole, (name, infl, reach)


def _carried(V, nd, seed, step=(0.05, -0.3, 0.02)):
    """End positions of a sweep that carries the dynamic vertices a long common step (a body falling or pushed as a
    whole, far longer than a cell) plus a small jitter of their own."""
    rng = np.random.default_rng(seed)
    dyn = np.arange(len(V))[:, None] < nd
    return V + np.where(dyn, np.asarray(step) + 3e-3 * rng.standard_normal(V.shape), 0.0)


@pytest.mark.parametrize("name", list(SCENES))
def test_co_moving_frame_keeps_every_pair_that_comes_near(name):
    """In the frame moving with the median displacement the query reports exactly the brute-force pairs of that
    frame's boxes (V1 - c; static vertices then move by -c), and every pair that comes within the inflation at a
    sampled time of the real sweep is among them. Also for a sweep of the moving vertices alone (the static cage
    then carries the median), and a query with still vertices."""
    V, E, F, nd = SCENES[name]()
    E, F = np.ascontiguousarray(E, dtype=np.int32), np.ascontiguousarray(F, dtype=np.int32)
    V1 = _carried(V, nd, 10)
    c = np.median(V1 - V, axis=0)
    for infl in (1e-3, 2e-2):
        got = _as_sets(*surface_candidates(V, V1, E, F, infl, nd, co_moving=True))
        shifted = brute_force(V, V1 - c, E, F, infl, nd)
        wide = brute_force(V, V1 - c, E, F, infl, nd, _scale_pad(V, V1, infl), moving=False)
        assert shifted[0] <= got[0] <= wide[0] and shifted[1] <= got[1] <= wide[1], (name, infl)
        assert _near_pairs_reported(V, V1, E, F, infl, nd, got, (name, infl)) > 0
    # still vertices (half the dynamic ones held) are left out of pairs among themselves in both frames
    still = np.zeros(len(V), dtype=bool)
    still[: nd // 2] = True
    V1s = np.where(still[:, None], V, V1)
    for co in (False, True):
        fv, ee = _as_sets(*surface_candidates(V, V1s, E, F, 2e-2, nd, still, co_moving=co))
        moving = ~still & (np.arange(len(V)) < nd)
        assert all(moving[F[f]].any() or moving[v] for f, v in fv)
        assert all(moving[E[a]].any() or moving[E[b]].any() for a, b in ee)


def test_co_moving_frame_is_the_plain_query_when_nothing_moves_together():
    """A median displacement of zero (most vertices held) leaves the query exactly as it was: same pair lists."""
    V, E, F, nd = ball_in_big_triangles()
    V1 = V.copy()
    V1[:5] += 0.1  # a few vertices moved, the median step is zero
    a = surface_candidates(V, V1, E, F, 1e-2, nd)
    b = surface_candidates(V, V1, E, F, 1e-2, nd, co_moving=True)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_co_moving_frame_sees_a_rigid_carry_as_standing_still():
    """Two boxes carried together by one long translation, 3 x their size: seen from the moving frame they stand
    still, so the query reports the pairs of the static query at the start (up to its few-ulp margin) and not the
    swept boxes' pairs between primitives that only travel side by side."""
    V, E, F, nd = two_boxes(gap=1e-3)
    V1 = V + np.array([0.0, 0.7, 3.0])
    infl = 2e-3
    co = _as_sets(*surface_candidates(V, V1, E, F, infl, nd, co_moving=True))
    still = brute_force(V, None, E, F, infl, nd)
    wide = brute_force(V, None, E, F, infl + 1e-12, nd)
    assert still[0] <= co[0] <= wide[0] and still[1] <= co[1] <= wide[1]
    swept = brute_force(V, V1, E, F, infl, nd, moving=False)
    assert len(swept[0]) + len(swept[1]) > 10 * (len(co[0]) + len(co[1]))


def test_large_inflation_overflows_the_first_pass():
    """Far more pairs than cell entries: the exact second pass must still give the brute-force set."""
    V, E, F, nd = triangle_soup(seed=4)
    fv, ee = surface_candidates(V, None, E, F, 0.5, nd)
    got = _as_sets(fv, ee)
    want = brute_force(V, None, E, F, 0.5, nd)
    assert got == want and len(ee) > len(E) * 5


def test_same_pairs_on_one_thread_and_deterministic():
    V, E, F, nd = ball_in_box()
    a = surface_candidates(V, None, E, F, 1e-2, nd)
    b = surface_candidates(V, None, E, F, 1e-2, nd)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))  # integer pair lists
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        c = surface_candidates(V, None, E, F, 1e-2, nd)
    finally:
        numba.set_num_threads(old)
    assert _as_sets(*a) == _as_sets(*c)


def _covered(coll, fv, ee, E, F):
    """Every ipctk collision maps to a candidate: FV -> (f, v), EE -> (a, b); EV and VV -> some fv
    or ee candidate containing all of their vertices."""
    fv_set = set(map(tuple, fv.tolist()))
    ee_set = set(map(tuple, ee.tolist()))
    for c in coll.fv_collisions:
        assert (c.face_id, c.vertex_id) in fv_set
    for c in coll.ee_collisions:
        assert (min(c.edge0_id, c.edge1_id), max(c.edge0_id, c.edge1_id)) in ee_set
    # vertex sets of all candidates, for the EV / VV checks
    cand = [set(F[f].tolist()) | {v} for f, v in fv_set] + [set(E[a].tolist()) | set(E[b].tolist()) for a, b in ee_set]
    by_vertex = {}
    for s in cand:
        for v in s:
            by_vertex.setdefault(v, []).append(s)
    for c in list(coll.ev_collisions) + list(coll.vv_collisions):
        ids = {int(i) for i in c.vertex_ids(E, F) if i >= 0}
        assert any(ids <= s for s in by_vertex.get(next(iter(ids)), [])), ids


@pytest.mark.parametrize("name", list(SCENES))
def test_complete_against_ipctk_collisions(name):
    V, E, F, nd = SCENES[name]()
    dhat = 5e-3
    mesh = ipctk.CollisionMesh(V, E, F)
    mesh.can_collide = ipctk.make_static_obstacle_filter(nd)
    coll = ipctk.NormalCollisions()
    coll.build(mesh, V, dhat)
    assert len(coll) > 0
    fv, ee = surface_candidates(V, None, E, F, dhat, nd)
    _covered(coll, fv, ee, E, F)


@pytest.mark.parametrize("name", ["two_boxes", "ball_in_big_triangles"])
def test_sweep_covers_ipctk_candidates(name):
    """ipctk's swept-box candidates, each box inflated by r, lie within ours with inflation 2 r (plus a hair: ipctk
    pads its boxes by a little more than r), except those whose moving boxes never meet at one time (ipctk's boxes
    cover the whole sweep at once)."""
    V0, E, F, nd = SCENES[name]()
    rng = np.random.default_rng(5)
    V1 = V0.copy()
    V1[:nd] += 0.02 * rng.standard_normal((nd, 3))
    r = 2e-3
    mesh = ipctk.CollisionMesh(V0, E, F)
    mesh.can_collide = ipctk.make_static_obstacle_filter(nd)
    cand = ipctk.Candidates()
    cand.build(mesh, V0, V1, r, ipctk.BruteForce())
    infl = 2 * r * (1 + 1e-3)
    fv, ee = surface_candidates(V0, V1, E, F, infl, nd)
    sfv, see = _as_sets(fv, ee)
    assert len(cand.fv_candidates) > 0 and len(cand.ee_candidates) > 0
    theirs_fv = {(c.face_id, c.vertex_id) for c in cand.fv_candidates}
    theirs_ee = {(min(c.edge0_id, c.edge1_id), max(c.edge0_id, c.edge1_id)) for c in cand.ee_candidates}
    meet_fv, meet_ee = brute_force(V0, V1, E, F, infl, nd)
    assert theirs_fv & meet_fv <= sfv and theirs_ee & meet_ee <= see
    assert len(theirs_fv & meet_fv) > 0.5 * len(theirs_fv)  # the check is not vacuous


def test_accepts_int64_ids_and_non_contiguous_positions():
    V, E, F, nd = ball_in_box()
    want = _as_sets(*surface_candidates(V, None, E, F, 1e-2, nd))
    got = _as_sets(*surface_candidates(np.asfortranarray(V), None, E.astype(np.int64), F.astype(np.int64), 1e-2, nd))
    assert got == want


def test_exclusions():
    # three stacked parallel triangles A (z=0), B (z=0.06), C (z=0.12); inflation 0.07 joins A-B and
    # B-C but not A-C. Within a triangle every pair passes the box test but shares a vertex.
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    V = np.vstack([tri, tri + np.array([0, 0, 0.06]), tri + np.array([0, 0, 0.12])])
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]], dtype=np.int32)
    E = ipctk.edges(F).astype(np.int32)
    tri_of_edge = E[:, 0] // 3

    fv, ee = surface_candidates(V, None, E, F, 0.07, num_dynamic=9)
    sfv, see = _as_sets(fv, ee)
    near = {(0, 1), (1, 0), (1, 2), (2, 1)}
    assert sfv == {(f, v) for f in range(3) for v in range(9) if (f, v // 3) in near}
    assert see == {(a, b) for a in range(9) for b in range(a + 1, 9) if (tri_of_edge[a], tri_of_edge[b]) in near}
    assert (sfv, see) == brute_force(V, None, E, F, 0.07, 9)

    # only A dynamic: the B-C pairs are all static and go, the A-B pairs stay
    fv, ee = surface_candidates(V, None, E, F, 0.07, num_dynamic=3)
    sfv, see = _as_sets(fv, ee)
    assert sfv == {(0, v) for v in range(3, 6)} | {(1, v) for v in range(3)}
    assert see == {(a, b) for a in range(9) for b in range(a + 1, 9) if {tri_of_edge[a], tri_of_edge[b]} == {0, 1}}

    # one dynamic vertex (0): faces B, C and vertices 1.. are static, face A is not
    fv, ee = surface_candidates(V, None, E, F, 0.07, num_dynamic=1)
    assert set(map(tuple, fv.tolist())) == {(0, v) for v in range(3, 6)} | {(1, 0)}
    assert all(0 in E[a] or 0 in E[b] for a, b in ee.tolist()) and len(ee) > 0

    fv, ee = surface_candidates(V, None, E, F, 0.07, num_dynamic=0)
    assert fv.shape == (0, 2) and ee.shape == (0, 2)


def test_all_static_pairs_are_skipped_in_a_scene():
    V, E, F, nd = ball_in_box(radius=0.99)
    fv, ee = surface_candidates(V, None, E, F, 2e-2, nd)
    assert np.all((F[fv[:, 0]].min(axis=1) < nd) | (fv[:, 1] < nd))
    assert np.all((E[ee[:, 0]].min(axis=1) < nd) | (E[ee[:, 1]].min(axis=1) < nd))
    # the static box's own near pairs are not there, the ball-box ones are
    static_face = F.min(axis=1) >= nd
    assert np.any(static_face[fv[:, 0]]) and np.any(~static_face[fv[:, 0]])


def test_bad_input():
    V, E, F, nd = two_boxes()
    with pytest.raises(ValueError):
        surface_candidates(V[:, :2], None, E, F, 1e-3, nd)
    with pytest.raises(ValueError):
        surface_candidates(V, V[:-1], E, F, 1e-3, nd)
    with pytest.raises(ValueError):
        surface_candidates(V, None, E, F + len(V), 1e-3, nd)
    with pytest.raises(ValueError):
        surface_candidates(V, None, E - 1, F, 1e-3, nd)
    with pytest.raises(ValueError):
        surface_candidates(V, None, E, F[:, :2], 1e-3, nd)
    with pytest.raises(ValueError):
        surface_candidates(V, None, E, F, -1.0, nd)
    bad = V.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        surface_candidates(bad, None, E, F, 1e-3, nd)


@pytest.mark.parametrize("sweep", SWEEPS)
@pytest.mark.parametrize("name", list(SCENES))
def test_still_vertices_leave_only_their_own_pairs_out(name, sweep):
    """``still`` marks vertices that do not move in the query: exactly the pairs made only of still or static
    vertices are left out, every other pair of the plain query is kept."""
    V, E, F, nd = SCENES[name]()
    rng = np.random.default_rng(11)
    V1 = sweep_end(V, nd, sweep, 11)
    still = rng.random(len(V)) < 0.5
    moving = (np.arange(len(V)) < nd) & ~still
    fv, ee = _as_sets(*surface_candidates(V, V1, E, F, 2e-2, nd, still))
    (lo_fv, lo_ee), (hi_fv, hi_ee) = _bounds(V, V1, E, F, 2e-2, nd)
    keep_fv = lambda pairs: {(f, v) for f, v in pairs if moving[v] or moving[F[f]].any()}  # noqa: E731
    keep_ee = lambda pairs: {(a, b) for a, b in pairs if moving[E[a]].any() or moving[E[b]].any()}  # noqa: E731
    assert keep_fv(lo_fv) <= fv <= keep_fv(hi_fv) and keep_ee(lo_ee) <= ee <= keep_ee(hi_ee)
    assert len(keep_fv(lo_fv)) < len(lo_fv) and len(keep_fv(lo_fv)) > 0  # the mask matters in every scene
    with pytest.raises(ValueError, match="still"):
        surface_candidates(V, V1, E, F, 2e-2, nd, still[:-1])


@pytest.mark.parametrize("sweep", SWEEPS)
@pytest.mark.parametrize("name", list(SCENES))
def test_a_group_leaves_only_the_pairs_among_its_own_vertices_out(name, sweep):
    """``group`` marks a prescribed set whose pairs among themselves are skipped whether they move or not: exactly
    the pairs whose every vertex is in it are left out, alone and together with ``still``."""
    V, E, F, nd = SCENES[name]()
    rng = np.random.default_rng(12)
    V1 = sweep_end(V, nd, sweep, 12)
    half = V[:, 0] < np.median(V[:, 0])  # a spatial half: many pairs among it, many across
    scattered = rng.random(len(V)) < 0.6  # every class of primitive (in, partly in, out) in every cell
    still = rng.random(len(V)) < 0.3
    (lo_fv, lo_ee), (hi_fv, hi_ee) = _bounds(V, V1, E, F, 2e-2, nd)
    for group, still_mask in itertools.product((half, scattered), (None, still)):
        fv, ee = _as_sets(*surface_candidates(V, V1, E, F, 2e-2, nd, still_mask, group))
        moving = (np.arange(len(V)) < nd) & (True if still_mask is None else ~still_mask)

        def keep_fv(pairs, group=group, moving=moving):
            return {
                (f, v) for f, v in pairs if not (group[v] and group[F[f]].all()) and (moving[v] or moving[F[f]].any())
            }

        def keep_ee(pairs, group=group, moving=moving):
            return {
                (a, b)
                for a, b in pairs
                if not (group[E[a]].all() and group[E[b]].all()) and (moving[E[a]].any() or moving[E[b]].any())
            }

        assert keep_fv(lo_fv) <= fv <= keep_fv(hi_fv) and keep_ee(lo_ee) <= ee <= keep_ee(hi_ee)
        assert len(keep_fv(lo_fv)) > 0  # the group leaves pairs in every scene
        assert len(keep_fv(lo_fv)) < len({p for p in lo_fv if moving[p[1]] or moving[F[p[0]]].any()})  # and takes some
    with pytest.raises(ValueError, match="group"):
        surface_candidates(V, V1, E, F, 2e-2, nd, None, group[:-1])
