"""idp.mesh.components: the same partition as scipy's connected_components, labelled by smallest vertex."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components as scipy_components

from idp.mesh.components import connected_components


@pytest.mark.parametrize("seed", range(5))
def test_same_partition_as_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 300))
    m = int(rng.integers(0, 2 * n))
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    count, labels = connected_components(n, a, b)
    ref_count, ref = scipy_components(sp.coo_matrix((np.ones(m), (a, b)), shape=(n, n)), directed=False)
    assert count == ref_count
    # one label per scipy component and vice versa
    pairs = np.unique(np.stack([labels, ref], axis=1), axis=0)
    assert pairs.shape[0] == count
    # components numbered in the order of their smallest vertex
    first = np.array([np.flatnonzero(labels == c).min() for c in range(count)])
    assert np.all(np.diff(first) > 0)


def test_no_edges_and_no_vertices() -> None:
    assert connected_components(3, np.zeros(0), np.zeros(0))[0] == 3
    count, labels = connected_components(0, np.zeros(0), np.zeros(0))
    assert count == 0 and labels.size == 0
