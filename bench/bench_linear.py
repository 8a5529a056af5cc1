"""Benchmark of the linear solver backends (not a test).

Builds elasticity-like SPD block matrices on a structured tet grid (edge blocks
[[B,-B],[-B,B]] with random SPD 3x3 B plus a lumped mass) at about 20K and 60K DOF and
times, per backend: ordering, symbolic analysis, first numeric factorisation, one solve,
and a refactorisation with the same pattern and new values. Then, for CHOLMOD, a pattern
change (near "contact" couplings) with a fresh ordering versus a reused one, and at 20K
the candidate methods for the scipy fallback (also on a heterogeneous, anisotropic
matrix). Prints tables and writes bench/results/linear.json.

    .venv/bin/python bench/bench_linear.py [--sizes 19 27] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from idp.solver.grid_matrices import grid_edges
from idp.solver.linear import LinearSolver, ScipySolver, available_solvers, have_pymetis


def edge_matrix(
    edges: np.ndarray, rng: np.random.Generator, nv: int, d: int = 3, hetero: bool = False
) -> sp.csr_matrix:
    """Sum over edges of [[B,-B],[-B,B]] with random SPD d x d blocks B.

    ``hetero``: B = s Q diag(1, 1e-3, 1e-3) Q^T with s = 10^U(-3, 3), a hard case for
    iterative solvers (stiffness contrast and anisotropy, as with tiny elements or barriers).
    """
    G = rng.standard_normal((len(edges), d, d))
    if hetero:
        Q, _ = np.linalg.qr(G)
        lam = np.r_[1.0, np.full(d - 1, 1e-3)]
        B = (Q * lam) @ Q.transpose(0, 2, 1) * (10.0 ** rng.uniform(-3, 3, len(edges)))[:, None, None]
    else:
        B = G @ G.transpose(0, 2, 1) + 0.1 * np.eye(d)
    B = 0.5 * (B + B.transpose(0, 2, 1))
    off = np.arange(d)
    di, dj = edges[:, 0, None] * d + off, edges[:, 1, None] * d + off
    R, C = [], []
    for r, c in ((di, di), (dj, dj), (di, dj), (dj, di)):
        R.append(np.broadcast_to(r[:, :, None], B.shape).ravel())
        C.append(np.broadcast_to(c[:, None, :], B.shape).ravel())
    V = np.concatenate([B.ravel(), B.ravel(), -B.ravel(), -B.ravel()])
    return sp.csr_matrix((V, (np.concatenate(R), np.concatenate(C))), shape=(nv * d, nv * d))


def make_matrix(
    nx: int, seed: int = 0, mass: float = 1.0, near_contacts: int = 0, hetero: bool = False
) -> sp.csr_matrix:
    """Tet-grid block matrix, 3 DOFs per vertex; optional couplings between vertices <= 3 cells apart."""
    rng = np.random.default_rng(seed)
    nv = nx**3
    A = edge_matrix(grid_edges(nx), rng, nv, hetero=hetero) + sp.diags(mass * rng.uniform(0.5, 1.5, 3 * nv))
    if near_contacts:
        crng = np.random.default_rng(99)
        i = crng.integers(0, nx, (near_contacts, 3))
        j = np.clip(i + crng.integers(-3, 4, (near_contacts, 3)), 0, nx - 1)
        a, b = np.ravel_multi_index(i.T, (nx,) * 3), np.ravel_multi_index(j.T, (nx,) * 3)
        keep = a != b
        A = A + edge_matrix(np.stack([a[keep], b[keep]], 1), rng, nv)
    A = sp.csr_matrix(A)
    A.sort_indices()
    return A


def new_solver(kind: str) -> LinearSolver:
    if kind.startswith("cholmod"):
        from idp.solver.cholmod_cvxopt import CholmodSolver

        return CholmodSolver(3, use_metis=(kind == "cholmod"), reuse_ordering=False)
    return ScipySolver(3, use_metis=(kind == "scipy"))


def res(A: sp.spmatrix, x: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(A @ x - b) / np.linalg.norm(b))


def bench_backend(kind: str, A: sp.csr_matrix, A2: sp.csr_matrix) -> dict[str, Any]:
    """First factorisation (split by stats), solve, and a same-pattern refactorisation."""
    s = new_solver(kind)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    t0 = time.perf_counter()
    s.factorize(A)
    first = time.perf_counter() - t0
    x = s.solve(b)
    st = dict(s.stats)
    t0 = time.perf_counter()
    s.factorize(A2)
    refactor = time.perf_counter() - t0
    x2 = s.solve(b)
    assert s.stats["symbolic_reuses"] == 1
    return {
        "backend": kind,
        "n": A.shape[0],
        "nnz": int(A.nnz),
        "ordering": st["ordering"],
        "symbolic": st["symbolic"],
        "numeric": st["numeric"],
        "solve": st["solve"],
        "first_factorize": first,
        "refactor": refactor,
        "residual": max(res(A, x, b), res(A2, x2, b)),
    }


def bench_pattern_change(nx: int, contacts: list[int]) -> list[dict[str, Any]]:
    """CHOLMOD after a pattern change: fresh nested dissection vs the previous ordering."""
    from cvxopt import cholmod

    from idp.solver.cholmod_cvxopt import CholmodSolver

    A = make_matrix(nx)
    b = np.ones(A.shape[0])
    rows = []
    for k in contacts:
        Ac = make_matrix(nx, near_contacts=k)
        for reuse in (False, True):
            s = CholmodSolver(3, reuse_ordering=reuse)
            s.factorize(A)
            before = dict(s.stats)
            t0 = time.perf_counter()
            s.factorize(Ac)
            total = time.perf_counter() - t0
            r = res(Ac, s.solve(b), b)  # before getfactor, which turns the factor back into a symbolic one
            rows.append(
                {
                    "n": A.shape[0],
                    "contacts": k,
                    "ordering_reused": reuse,
                    "ordering": s.stats["ordering"] - before["ordering"],
                    "symbolic": s.stats["symbolic"] - before["symbolic"],
                    "numeric": s.stats["numeric"] - before["numeric"],
                    "total": total,
                    "nnz_L": len(cholmod.getfactor(s._F)),
                    "residual": r,
                }
            )
    return rows


def timed(f: Callable[[], np.ndarray], A: sp.spmatrix, b: np.ndarray) -> tuple[float, float]:
    t0 = time.perf_counter()
    x = f()
    return time.perf_counter() - t0, res(A, x, b)


def bench_fallback_candidates(nx: int) -> list[dict[str, Any]]:
    """Factor+solve of the scipy candidates, on an easy and a hard (heterogeneous) matrix."""
    rows = []
    for label, mass, hetero in (("mass-dominated", 1.0, False), ("hetero, mass 1e-4", 1e-4, True)):
        A = make_matrix(nx, mass=mass, hetero=hetero)
        b = np.random.default_rng(2).standard_normal(A.shape[0])
        Acsc = A.tocsc()

        def splu(spec: str) -> Callable[[], np.ndarray]:
            opts = {"SymmetricMode": True}
            return lambda: spla.splu(Acsc, permc_spec=spec, diag_pivot_thresh=0.0, options=opts).solve(b)

        def nd() -> np.ndarray:
            s = ScipySolver(3, use_metis=True)
            s.factorize(A)
            return s.solve(b)

        its = [0]

        def cg() -> np.ndarray:
            def count(_: np.ndarray) -> None:
                its[0] += 1

            M = sp.diags(1.0 / A.diagonal())
            x, _info = spla.cg(A, b, rtol=1e-11, M=M, maxiter=A.shape[0], callback=count)
            return x

        cands: dict[str, Callable[[], np.ndarray]] = {
            "splu MMD_AT_PLUS_A, no pivoting": splu("MMD_AT_PLUS_A"),
            "splu COLAMD, no pivoting": splu("COLAMD"),
            "spsolve (COLAMD, pivoting)": lambda: spla.spsolve(Acsc, b),
            "CG + Jacobi, rtol 1e-11": cg,
        }
        if have_pymetis():
            cands["splu + METIS ND (idp 'scipy')"] = nd
        for name, f in cands.items():
            t, r = timed(f, A, b)
            rows.append(
                {
                    "matrix": label,
                    "n": A.shape[0],
                    "method": name,
                    "seconds": t,
                    "residual": r,
                    "iterations": its[0] if name.startswith("CG") else None,
                }
            )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[19, 27], help="grid vertices per side (3*n^3 DOF)")
    ap.add_argument("--quick", action="store_true", help="skip the pattern-change and fallback studies")
    args = ap.parse_args()

    kinds = []
    if "cholmod" in available_solvers():
        kinds += ["cholmod", "cholmod-amd"] if have_pymetis() else ["cholmod-amd"]
    kinds += ["scipy", "scipy-mmd"] if have_pymetis() else ["scipy-mmd"]

    out: dict[str, Any] = {
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "loadavg_start": os.getloadavg(),
            "threads_env": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
        },
        "backends": [],
        "pattern_change": [],
        "fallback_candidates": [],
    }
    print(
        f"{'backend':12s} {'n':>7s} {'nnz':>9s} {'ordering':>9s} {'symbolic':>9s} {'numeric':>8s} "
        f"{'solve':>7s} {'refactor':>9s} {'residual':>9s}"
    )
    for nx in args.sizes:
        A, A2 = make_matrix(nx, seed=0), make_matrix(nx, seed=1)
        for kind in kinds:
            if kind == "scipy-mmd" and A.shape[0] > 30000:
                continue  # 42 s per factorisation at 59K DOF: measured once, see the docstring of linear.py
            r = bench_backend(kind, A, A2)
            out["backends"].append(r)
            print(
                f"{kind:12s} {r['n']:7d} {r['nnz']:9d} {r['ordering']:9.3f} {r['symbolic']:9.3f} "
                f"{r['numeric']:8.3f} {r['solve']:7.3f} {r['refactor']:9.3f} {r['residual']:9.1e}",
                flush=True,
            )

    if not args.quick and "cholmod" in kinds:
        print("\nCHOLMOD after a pattern change (near couplings added): fresh ND vs reused ordering")
        print(
            f"{'n':>7s} {'contacts':>8s} {'reuse':>6s} {'ordering':>9s} {'symbolic':>9s} "
            f"{'numeric':>8s} {'nnz(L)':>11s}"
        )
        for r in bench_pattern_change(args.sizes[-1], [10, 100, 1000]):
            out["pattern_change"].append(r)
            print(
                f"{r['n']:7d} {r['contacts']:8d} {r['ordering_reused']!s:>6s} {r['ordering']:9.3f} "
                f"{r['symbolic']:9.3f} {r['numeric']:8.3f} {r['nnz_L']:11d}",
                flush=True,
            )
    if not args.quick:
        print(f"\nscipy fallback candidates, factor + solve at nx={args.sizes[0]}")
        for r in bench_fallback_candidates(args.sizes[0]):
            out["fallback_candidates"].append(r)
            extra = f"  ({r['iterations']} its)" if r["iterations"] else ""
            print(
                f"{r['matrix']:18s} {r['n']:7d} {r['method']:32s} {r['seconds']:7.2f} s  res {r['residual']:.1e}"
                + extra,
                flush=True,
            )

    out["machine"]["loadavg_end"] = os.getloadavg()
    path = Path(__file__).resolve().parent / "results" / "linear.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
