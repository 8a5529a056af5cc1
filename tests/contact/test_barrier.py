"""Finite-difference checks of the IPC barrier wrapper (value / gradient / Hessian) and CCD/κ behaviour."""

import itertools

import numpy as np
import pytest

from idp.contact.model import ContactModel
from idp.mesh.generate import polygon_box, tet_box
from idp.mesh.surface import boundary_faces


def two_boxes(gap: float, rng: np.random.Generator, jitter: float = 0.0):
    """Two tet boxes stacked along z with a small gap: many point-triangle and edge-edge pairs within dhat."""
    a = tet_box((0, 0, 0), (1, 1, 1), (2, 2, 2))
    b = tet_box((0.3, 0.2, 1 + gap), (1.3, 1.2, 2 + gap), (2, 2, 2))
    x = np.vstack([a.vertices, b.vertices])
    x = x + jitter * rng.standard_normal(x.shape)
    surf = np.vstack([boundary_faces(a.elements), boundary_faces(b.elements) + a.vertices.shape[0]])
    return x, surf, x.shape[0]


def fd_gradient(f, x, eps):
    g = np.zeros(x.size)
    flat = x.ravel()
    for i in range(flat.size):
        xp, xm = flat.copy(), flat.copy()
        xp[i] += eps
        xm[i] -= eps
        g[i] = (f(xp.reshape(x.shape)) - f(xm.reshape(x.shape))) / (2 * eps)
    return g


@pytest.mark.parametrize("barrier", ["compiled", "ipctk"])
@pytest.mark.parametrize("seed,gap,kappa", [(0, 0.02, 1.0), (1, 0.05, 10.0), (2, 0.01, 1e3)])
def test_barrier_gradient_and_hessian_match_finite_differences(seed, gap, kappa, barrier):
    rng = np.random.default_rng(seed)
    x, surf, n_dyn = two_boxes(gap, rng, jitter=1e-3)
    cm = ContactModel(x, surf, n_dyn, dhat=0.1, kappa=kappa, barrier=barrier)
    ev = cm.evaluate(x)
    assert ev.num_active > 10
    to_cm = cm.to_full

    def value(y):
        return cm.value(cm.evaluate(y))

    g = cm.gradient(ev)
    eps = 1e-7
    g_fd_full = fd_gradient(value, x, eps).reshape(x.shape)
    g_fd = g_fd_full[to_cm].ravel()
    assert np.linalg.norm(g - g_fd) <= 1e-5 * np.linalg.norm(g) + 1e-9

    H = cm.hessian(ev, project=False).toarray()
    # FD of the gradient along a few random directions
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        v[~np.isin(np.arange(x.shape[0]), to_cm)] = 0
        gp = cm.gradient(cm.evaluate(x + eps * v))
        gm = cm.gradient(cm.evaluate(x - eps * v))
        hv_fd = (gp - gm) / (2 * eps)
        hv = H @ v[to_cm].ravel()
        assert np.linalg.norm(hv - hv_fd) <= 1e-4 * np.linalg.norm(hv) + 1e-8

    Hp = cm.hessian(ev, project=True).toarray()
    assert np.allclose(Hp, Hp.T, atol=1e-8 * np.abs(Hp).max())
    assert np.linalg.eigvalsh(Hp).min() >= -1e-8 * np.abs(Hp).max()


def test_barrier_is_zero_beyond_dhat_and_grows_towards_contact():
    rng = np.random.default_rng(0)
    x, surf, n_dyn = two_boxes(0.3, rng)
    cm = ContactModel(x, surf, n_dyn, dhat=0.1, kappa=1.0)
    assert cm.evaluate(x).num_active == 0 and cm.value(cm.evaluate(x)) == 0.0
    values = []
    for gap in (0.08, 0.04, 0.01, 0.001):
        y, _, _ = two_boxes(gap, rng)
        values.append(cm.value(cm.evaluate(y)))
    assert all(b > a for a, b in itertools.pairwise(values))


def test_ccd_stops_a_step_that_would_pass_through():
    rng = np.random.default_rng(0)
    x, surf, n_dyn = two_boxes(0.05, rng)
    cm = ContactModel(x, surf, n_dyn, dhat=0.01)
    y = x.copy()
    y[n_dyn // 2 :, 2] -= 0.5  # the upper box moves down through the lower one
    alpha = cm.max_collision_free_step(x, y)
    assert 0 < alpha < 0.1
    assert not cm.has_intersections(x + alpha * (y - x))
    assert cm.has_intersections(y)


def test_static_obstacle_pairs_are_skipped_and_2d_works():
    # 2D: a square of triangles inside a fixed square polyline cage
    from idp.mesh.generate import tri_rectangle

    body = tri_rectangle((-0.5, -0.5), (0.5, 0.5), (3, 3))
    cage = polygon_box((-0.52, -0.52), (0.52, 0.52), 4)
    x = np.vstack([body.vertices, cage.vertices])
    surf = np.vstack([boundary_faces(body.elements), cage.faces + body.vertices.shape[0]])
    cm = ContactModel(x, surf, body.vertices.shape[0], dhat=0.05, kappa=1.0)
    ev = cm.evaluate(x)
    assert ev.num_active > 0 and 0.01 < cm.min_distance(ev) < 0.05
    assert cm.gradient(ev).shape == (2 * cm.to_full.size,)


def test_initial_kappa_is_positive_and_update_doubles_when_distance_shrinks():
    rng = np.random.default_rng(0)
    x, surf, n_dyn = two_boxes(0.02, rng)
    cm = ContactModel(x, surf, n_dyn, dhat=0.05)
    ev = cm.evaluate(x)
    k0 = cm.initialize_kappa(ev, np.zeros(ev.surface_positions.size), average_mass=1.0)
    assert k0 > 0 and cm.kappa_max >= k0
    tiny = 1e-10 * cm.bbox_diagonal
    k1 = cm.update_kappa(2 * tiny, tiny)
    assert k1 == pytest.approx(2 * k0)


def test_swept_candidates_give_the_same_collision_sets_along_the_segment():
    rng = np.random.default_rng(3)
    x, surf, n_dyn = two_boxes(0.05, rng)
    cm = ContactModel(x, surf, n_dyn, dhat=0.02, kappa=1.0)
    y = x.copy()
    y[n_dyn // 2 :, 2] -= 0.04
    cand = cm.sweep_candidates(x, y)
    assert cm.max_collision_free_step(x, y, cand) == pytest.approx(cm.max_collision_free_step(x, y), rel=1e-6)
    for a in (0.0, 0.3, 0.7, 1.0):
        z = x + a * (y - x)
        e1, e2 = cm.evaluate(z), cm.evaluate(z, cand)
        assert e1.num_active == e2.num_active
        assert cm.value(e1) == pytest.approx(cm.value(e2), rel=1e-12)


def test_tight_inclusion_falls_back_to_additive_ccd_when_nearly_touching():
    rng = np.random.default_rng(4)
    x, surf, n_dyn = two_boxes(0.05, rng)
    cm = ContactModel(x, surf, n_dyn, dhat=0.01, ccd="tight_inclusion")
    y = x.copy()
    y[n_dyn // 2 :, 2] -= 0.5
    a_ti = cm.max_collision_free_step(x, y)
    assert cm.ccd_fallbacks == 0 and 0 < a_ti < 0.1
    a_fb = cm.max_collision_free_step(x, y, current_min_distance=1e-12)
    assert cm.ccd_fallbacks == 1 and 0 < a_fb < 0.1
    assert not cm.has_intersections(x + a_fb * (y - x))
