"""The compiled barrier (idp.contact.compiled_barrier) against ipctk's NormalCollisions / BarrierPotential.

Scenes are built to exercise every collision kind: two stacked jittered boxes (point–plane, edge–edge,
and parallel edges, i.e. mollified edge–edge pairs, when not jittered), a tilted box over a static
floor (obstacle pairs, whose blocks shrink when static vertices are dropped), and a box pushed onto a
static cage corner (edge–vertex and vertex–vertex pairs)."""

import numpy as np
import pytest

from idp.contact.model import ContactModel
from idp.mesh.generate import tet_box
from idp.mesh.surface import boundary_faces


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def stacked(gap, jitter, seed, tilt=0.0, static_lower=False):
    rng = np.random.default_rng(seed)
    a = tet_box((0, 0, 0), (1, 1, 1), (3, 3, 2))
    b = tet_box((0.3, 0.2, 1 + gap), (1.3, 1.2, 2 + gap), (3, 3, 2))
    vb = b.vertices
    if tilt:
        c = vb.mean(axis=0)
        vb = (vb - c) @ _rotation((1, 0.3, 0), tilt).T + c
        vb[:, 2] += (1 + gap) - vb[:, 2].min()
    vb = vb + jitter * rng.standard_normal(vb.shape)
    fa, fb = boundary_faces(a.elements), boundary_faces(b.elements)
    if static_lower:  # the lower box is a static obstacle: dynamic vertices first
        x = np.vstack([vb, a.vertices])
        surf = np.vstack([fb, fa + vb.shape[0]])
        return x, surf, vb.shape[0]
    x = np.vstack([a.vertices, vb])
    surf = np.vstack([fa, fb + a.vertices.shape[0]])
    return x, surf, x.shape[0]


def corner(gap, seed=3):
    """Two dynamic boxes beside a static one, one along an edge and one at a corner (EV / VV pairs)."""
    rng = np.random.default_rng(seed)
    cage = tet_box((0, 0, 0), (1, 1, 1), (2, 2, 2))
    e = tet_box((1 + gap, 1 + gap, 0.1), (2, 2, 0.9), (2, 2, 2))
    c = tet_box((1 + gap, 1 + gap, 1 + gap), (2, 2, 2), (2, 2, 2))
    ve = e.vertices + 1e-3 * gap * rng.standard_normal(e.vertices.shape)
    vc = c.vertices + 1e-3 * gap * rng.standard_normal(c.vertices.shape)
    x = np.vstack([ve, vc, cage.vertices])
    n1, n2 = ve.shape[0], ve.shape[0] + vc.shape[0]
    surf = np.vstack([boundary_faces(e.elements), boundary_faces(c.elements) + n1, boundary_faces(cage.elements) + n2])
    return x, surf, n2


SCENES = {
    "stacked_jittered": lambda: stacked(0.01, 2e-3, 0),
    "stacked_parallel": lambda: stacked(0.01, 0.0, 1),
    "tilted_on_static": lambda: stacked(0.004, 1e-3, 2, tilt=0.05, static_lower=True),
    "corner": lambda: corner(0.01),
}


def both(scene, dhat=0.05, kappa=3.0):
    x, surf, n_dyn = SCENES[scene]()
    ref = ContactModel(x, surf, n_dyn, dhat=dhat, kappa=kappa, barrier="ipctk")
    new = ContactModel(x, surf, n_dyn, dhat=dhat, kappa=kappa, barrier="compiled")
    return x, ref, new


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_same_collision_set_value_gradient_and_hessians_as_ipctk(scene):
    x, ref, new = both(scene)
    er, en = ref.evaluate(x), new.evaluate(x)
    assert er.num_active > 5
    assert en.num_active == er.num_active
    assert new.min_distance(en) == pytest.approx(ref.min_distance(er), rel=1e-12)
    assert new.value(en) == pytest.approx(ref.value(er), rel=1e-10)
    gr, gn = ref.gradient(er), new.gradient(en)
    assert np.linalg.norm(gn - gr) <= 1e-10 * np.linalg.norm(gr)
    for project in (False, True):  # whole local blocks, as ipctk projects them
        Hr, Hn = ref.hessian(er, project).toarray(), new.hessian(en, project).toarray()
        assert np.abs(Hn - Hr).max() <= 1e-8 * np.abs(Hr).max(), project


def test_kinds_covered():
    """The scenes above do reach every collision kind (else the comparison proves less than it says)."""
    from idp.contact._distance_kernels import LL, PL, PP, PPLANE

    kinds, mollified = set(), 0
    for scene in SCENES:
        x, _, new = both(scene)
        cs = new.evaluate(x).collisions
        kinds |= set(np.unique(cs.kind).tolist())
        mollified += int((cs.eps > 0).sum())
    assert kinds == {PP, PL, PPLANE, LL}
    assert mollified > 0


@pytest.mark.parametrize("scene", ["tilted_on_static", "corner", "stacked_jittered"])
def test_restricted_blocks_are_the_projected_principal_blocks(scene):
    """Blocks on the kept vertices: unprojected, the principal submatrix of ipctk's Hessian; projected,
    PSD and equal to the PSD projection of that submatrix."""
    x, ref, new = both(scene)
    er, en = ref.evaluate(x), new.evaluate(x)
    nv = en.surface_positions.shape[0]
    rng = np.random.default_rng(0)
    keep = np.arange(nv) < new.num_dynamic_collision_vertices
    keep &= rng.random(nv) > 0.2  # also drop some "pinned" dynamic vertices
    vmap = np.where(keep, np.cumsum(keep) - 1, -1)
    dofs = np.flatnonzero(np.repeat(keep, 3))
    Hr = ref.hessian(er, project=False).toarray()[np.ix_(dofs, dofs)]
    from idp.contact.compiled_barrier import blocks_to_coo

    n = 3 * int(keep.sum())
    for project in (False, True):
        bv, blocks = new.hessian_blocks(en, vmap, project)
        r, c, v = blocks_to_coo(bv, blocks)
        Hn = np.zeros((n, n))
        np.add.at(Hn, (r, c), v)
        if not project:
            assert np.abs(Hn - Hr).max() <= 1e-8 * np.abs(Hr).max()
        else:
            scale = np.abs(Hn).max()
            assert np.abs(Hn - Hn.T).max() <= 1e-12 * scale
            assert np.linalg.eigvalsh(Hn).min() >= -1e-9 * scale
            for k in range(bv.shape[0]):  # each block: the projection of its unprojected block
                m = 3 * int((bv[k] >= 0).sum())
                if m == 0:
                    continue
                B = blocks[k, :m, :m]
                assert np.linalg.eigvalsh(B).min() >= -1e-9 * max(np.abs(B).max(), 1e-300)


def test_blocks_of_a_range_of_collisions_are_those_of_the_whole_set():
    """``rows=(c0, c1)``: the blocks of those collisions only, bit for bit the whole set's rows c0 … c1 − 1; a range
    outside the set is refused."""
    from idp.contact import compiled_barrier as cb

    x, _, new = both("stacked_jittered")
    en = new.evaluate(x)
    vs = en.surface_positions
    vmap = np.arange(vs.shape[0], dtype=np.int64)
    cs = en.collisions
    m = len(cs)
    assert m > 4
    bv, blocks = cb.barrier_hessian_blocks(cs, vs, new.dhat, new.kappa, vmap, True)
    c0, c1 = 2, m - 1
    rbv, rblocks = cb.barrier_hessian_blocks(cs, vs, new.dhat, new.kappa, vmap, True, rows=(c0, c1))
    assert rbv.shape == (c1 - c0, 4)
    for g, w in zip(cb.blocks_to_coo(rbv, rblocks), cb.blocks_to_coo(bv[c0:c1], blocks[c0:c1]), strict=True):
        np.testing.assert_array_equal(g, w)
    with pytest.raises(ValueError, match="outside"):
        cb.barrier_hessian_blocks(cs, vs, new.dhat, new.kappa, vmap, True, rows=(0, m + 1))


def test_swept_candidates_cover_the_segment():
    x, ref, new = both("stacked_jittered", dhat=0.02)
    y = x.copy()
    y[y[:, 2] > 1.005, 2] -= 0.03
    cand = new.sweep_candidates(x, y)
    for a in (0.0, 0.4, 1.0):
        z = x + a * (y - x)
        e1, e2 = new.evaluate(z), new.evaluate(z, cand)
        assert e1.num_active == e2.num_active == ref.evaluate(z).num_active
        assert new.value(e1) == pytest.approx(new.value(e2), rel=1e-12)
    assert new.max_collision_free_step(x, y, cand) == pytest.approx(ref.max_collision_free_step(x, y), rel=1e-6)


def test_repeated_edge_vertex_pairs_merge_into_the_first_with_their_count():
    """_merge_repeated keeps the first (in index order) of each key >= 0 and counts its repeats; keys < 0 (pairs
    that are never merged) are all kept with weight 1."""
    from idp.contact.compiled_barrier import _merge_repeated

    rng = np.random.default_rng(3)
    nv, m = 40, 3000
    verts = np.full((m, 4), -1, np.int32)
    verts[:, 0] = rng.integers(0, nv, m)
    other = rng.integers(0, 6, m)
    key = np.where(rng.random(m) < 0.2, -1, verts[:, 0].astype(np.int64) * 10 + other)
    keep, weight = _merge_repeated(key, verts, nv)
    first: dict[int, int] = {}
    count: dict[int, int] = {}
    for c, k in enumerate(key.tolist()):
        if k >= 0:
            first.setdefault(k, c)
            count[k] = count.get(k, 0) + 1
    want_keep = np.array([k < 0 or first[k] == c for c, k in enumerate(key.tolist())])
    want_weight = np.array([1.0 if k < 0 or first[k] != c else float(count[k]) for c, k in enumerate(key.tolist())])
    assert np.array_equal(keep, want_keep)
    assert np.array_equal(weight[keep], want_weight[keep])


@pytest.mark.parametrize("scene", ["corner", "stacked_jittered"])
def test_compaction_on_one_thread_or_all_gives_the_same_set(scene, monkeypatch):
    """The collision compaction runs on one thread or on all as idp.thread_choice finds faster: both ways give the
    same collisions, in the same order, with the same weights (here with many chunks: a large d̂ and an extra
    copy of the candidate lists)."""
    import numba

    from idp.contact import compiled_barrier as cb
    from idp.thread_choice import ThreadChoice

    x, _, model = both(scene, dhat=0.3)
    vs = model.surface_positions(x)
    fv, ee = model._candidates(vs, None)
    reps = max(1, 40_000 // max(fv.shape[0] + ee.shape[0], 1))  # > 16,384 candidates: several chunks
    fv, ee = np.tile(fv, (reps, 1)), np.tile(ee, (reps, 1))
    sets = []
    for way in (False, True):
        monkeypatch.setattr(cb, "_COMPACT_THREADS", ThreadChoice(force=way))
        sets.append(cb.build_collision_set(vs, model._edges, model._faces, fv, ee, 0.3, model._edge_rest_len2))
    one, every = sets
    assert numba.get_num_threads() >= 1 and len(one) > 10
    for name in ("verts", "kind", "local", "eps", "weight", "sqdist"):
        np.testing.assert_array_equal(getattr(one, name), getattr(every, name), err_msg=name)
