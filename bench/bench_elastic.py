"""Times ElasticEnergy.value_gradient_hessian on a random ~60K-tet structured mesh.

Usage: .venv/bin/python bench/bench_elastic.py [cells_x cells_y cells_z]
Prints one line per (model, projection): first call (includes numba compile or cache load
for the first row) and the best of 5 further calls.
"""

from __future__ import annotations

import itertools
import sys
import time

import numpy as np

from idp.energies.elastic import ElasticEnergy


def tet_grid(nx: int, ny: int, nz: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit-spaced grid of nx*ny*nz cubes, 6 positively oriented tets per cube (Kuhn split)."""
    dims = (nx + 1, ny + 1, nz + 1)
    X = np.stack(np.meshgrid(*[np.arange(n, dtype=float) for n in dims], indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(X.shape[0]).reshape(dims)
    base = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), axis=-1).reshape(-1, 3)
    tets = []
    for perm in itertools.permutations(range(3)):
        off = np.zeros(3, int)
        path = [idx[tuple(base.T)]]
        for ax in perm:
            off[ax] = 1
            path.append(idx[tuple((base + off).T)])
        tets.append(np.stack(path, axis=1))
    T = np.concatenate(tets)
    Dm = np.transpose(X[T[:, 1:]] - X[T[:, :1]], (0, 2, 1))
    neg = np.linalg.det(Dm) < 0
    T[neg, 0], T[neg, 1] = T[neg, 1].copy(), T[neg, 0].copy()
    return X, T


def main() -> None:
    nx, ny, nz = (int(a) for a in sys.argv[1:4]) if len(sys.argv) >= 4 else (25, 20, 20)
    X, T = tet_grid(nx, ny, nz)
    rng = np.random.default_rng(0)
    x = np.ascontiguousarray(X + 0.1 * rng.uniform(-1, 1, X.shape))
    print(f"{len(T)} tets, {len(X)} vertices")
    print(f"{'model':<20} {'project':<8} {'first [s]':>10} {'best of 5 [s]':>14}")
    for model in ("neo_hookean", "symmetric_dirichlet"):
        E = ElasticEnergy(model, X, T, 1e5, 0.45)
        for project in (True, False):
            t0 = time.perf_counter()
            E.value_gradient_hessian(x, project=project)
            first = time.perf_counter() - t0
            best = np.inf
            for _ in range(5):
                t0 = time.perf_counter()
                E.value_gradient_hessian(x, project=project)
                best = min(best, time.perf_counter() - t0)
            print(f"{model:<20} {project!s:<8} {first:>10.3f} {best:>14.4f}")


if __name__ == "__main__":
    main()
