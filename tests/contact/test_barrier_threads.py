"""The barrier evaluated by ipctk (2D, ``barrier = "ipctk"``) is a function of its inputs alone.

ipctk builds its collision set on its threads and sums the barrier over per-thread parts; before
:func:`idp.contact.model.one_ipctk_thread` wrapped those calls, evaluating this very configuration 20 times on two
ipctk threads gave 9 different values, 14 different gradients and 19 different Hessians (the last bits), so a
resumed 2D run was not byte for byte the uninterrupted one."""

import ipctk
import numpy as np
import pytest

from idp.contact.model import ContactModel


def _packed_polygons(rows: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """rows × rows closed 12-gons of radius 0.0499 on a 0.1 grid, jittered: every neighbour pair within d̂."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 2.0 * np.pi, 13)[:-1]
    ring = np.c_[np.arange(12), np.roll(np.arange(12), -1)]
    points, edges = [], []
    for k in range(rows * rows):
        centre = 0.1 * np.array([k // rows, k % rows], dtype=float)
        points.append(centre + 0.0499 * np.c_[np.cos(t), np.sin(t)] + rng.normal(0.0, 1e-4, (12, 2)))
        edges.append(ring + 12 * k)
    return np.vstack(points), np.vstack(edges)


@pytest.mark.parametrize("threads", [2, 4])
def test_ipctk_barrier_is_the_same_on_every_evaluation(threads):
    x, edges = _packed_polygons()
    model = ContactModel(x, edges, x.shape[0], dhat=5e-3, kappa=3.0, barrier="ipctk")
    before = ipctk.get_num_threads()
    seen: dict[str, set] = {"pairs": set(), "value": set(), "gradient": set(), "hessian": set()}
    try:
        ipctk.set_num_threads(threads)
        threads = ipctk.get_num_threads()  # (ipctk caps the count at the machine's)
        for _ in range(12):
            ev = model.evaluate(x, model.sweep_candidates(x, x + 1e-3))
            H = model.hessian(ev).tocsr()
            H.sort_indices()
            seen["pairs"].add(ev.num_active)
            seen["value"].add(model.value(ev))
            seen["gradient"].add(model.gradient(ev).tobytes())
            seen["hessian"].add(H.data.tobytes() + H.indices.tobytes())
            assert ipctk.get_num_threads() == threads  # restored after each call
    finally:
        ipctk.set_num_threads(before)
    assert min(seen["pairs"]) > 2000
    # identical by construction: every call on one thread, in ipctk's serial order
    assert {k: len(v) for k, v in seen.items()} == {"pairs": 1, "value": 1, "gradient": 1, "hessian": 1}
