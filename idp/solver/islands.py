"""Islands of a Newton move: groups of bodies that cannot reach one another along it, each given its own step.

The step energy of groups of bodies that share no element, no pair term (sticky links) and no contact candidate
of the move is the sum of their own energies, and the Newton direction of the whole is one independent direction
per group. One step length for the whole move lets the group whose move CCD or the inversion filter cuts shortest
hold back every other one: three flowers on their stems that settle in 22, 35 and 38 Newton iterations alone took
190 together (docs/benchmarks.md, "Islands"). The Newton loop therefore scales each island's part of the move by
that island's own feasible fraction (its elements' inversion filter and its candidates' CCD), then backtracks on
the total energy as before. Every island's move is inversion- and collision-free by its own filters, and no two
islands can meet: the broad phase of the whole move (boxes inflated by d̂) pairs none of their primitives, and each
island's scaled move stays inside its own boxes.

Only the compiled 3D barrier is handled (its candidates are plain (fv, ee) arrays); kinematic tools, which couple
every body they touch through one unknown, turn islands off for the iteration (``StepSolver._solve``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idp.mesh.components import connected_components


@dataclass
class BodyLabels:
    """Connected components ("bodies") of a system's vertices over every element stencil and pair term."""

    vertex_label: np.ndarray  # (n,) int64: the vertex's component; −1 for a vertex without a free DOF
    num_labels: int
    term_labels: list[np.ndarray]  # per term of ``system.terms``: the label of its stencils (none or one)


def body_labels(system) -> BodyLabels:
    """Label the vertices of ``system`` by the component of the graph whose edges are its stencils (elements, shell
    hinges, ...), its pair terms' pairs, and each term's stencils among themselves (a term spanning several bodies
    makes them one). Vertices no free DOF moves get −1: they take no part in any move."""
    n, d = system.x.shape
    heads, tails = [], []
    stencil_vertices = []
    for wt in system.terms:
        dofs = np.asarray(wt.term.element_dofs(), dtype=np.int64)
        verts = dofs[:, ::d] // d if dofs.size else np.zeros((0, 1), dtype=np.int64)
        stencil_vertices.append(verts)
        for j in range(1, verts.shape[1]):
            heads.append(verts[:, 0])
            tails.append(verts[:, j])
        if verts.shape[0] > 1:  # a term's value is one number: the bodies it spans move as one
            heads.append(np.full(verts.shape[0] - 1, verts[0, 0]))
            tails.append(verts[1:, 0])
    for t in system.pair_terms:
        pairs = np.asarray(t.pairs, dtype=np.int64).reshape(-1, 2)
        heads.append(pairs[:, 0])
        tails.append(pairs[:, 1])
    _, comp = connected_components(n, _joined(heads), _joined(tails))
    free = system.dof_map.free_mask.reshape(n, d).any(axis=1)
    comp = np.where(free, comp, -1).astype(np.int64)
    # renumber the used components 0..k−1
    used, label = np.unique(comp[comp >= 0], return_inverse=True)
    vertex_label = np.full(n, -1, dtype=np.int64)
    vertex_label[comp >= 0] = label
    term_labels = []
    for verts in stencil_vertices:
        lab = vertex_label[verts.ravel()]
        term_labels.append(np.unique(lab[lab >= 0]))
    return BodyLabels(vertex_label, int(used.size), term_labels)


def merge_labels(num_labels: int, groups: np.ndarray) -> tuple[int, np.ndarray]:
    """Islands of labels joined by ``groups`` ((k, m) labels, −1 for none; every row's labels join one island).
    Returns (number of islands, island of each label)."""
    groups = np.asarray(groups, dtype=np.int64)
    if groups.ndim == 1:
        groups = groups[:, None]
    heads, tails = [], []
    if groups.size:
        # each row: join every valid label to the row's first valid one
        valid = groups >= 0
        first_col = np.argmax(valid, axis=1)
        any_valid = valid.any(axis=1)
        anchor = groups[np.arange(groups.shape[0]), first_col]
        for j in range(groups.shape[1]):
            keep = any_valid & valid[:, j]
            heads.append(anchor[keep])
            tails.append(groups[keep, j])
    return connected_components(num_labels, _joined(heads), _joined(tails))


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The edge ends of ``parts`` in one int64 array (empty when there are none)."""
    return np.concatenate(parts).astype(np.int64, copy=False) if parts else np.zeros(0, dtype=np.int64)
