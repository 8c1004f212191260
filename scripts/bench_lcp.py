"""PGS LCP throughput against Clarabel solving the same LCPs as QPs, one problem at a time.

``python scripts/bench_lcp.py [--device cpu] [--dtype float64] [--batch 4096] [--n 30] [--kinds pd psd]
[--threads T] [--clarabel-subset 256] [--json OUT]``

Problems: :func:`torchhand.solvers.lcp.random_lcp` (the tests' builder): symmetric positive definite M = A A^T / n + 0.1 I
(condition number about 40 at n = 30) or rank-n/2 positive semidefinite M = A A^T / n, with a planted solution.
torchhand: :func:`torchhand.kernels.lcp.solve_lcp_pgs` on the whole batch with tol = 1e-6 on ||min(x, Mx + q)||_inf,
as plain PGS (omega = 1), SOR (omega = 1.2), SOR with float32 sweeps refined against exact float64 checks
(``mixed``), all checking every 5 sweeps, and PGS with subspace minimisation (checks every 10).
Threads: ``--threads`` (default 1, the same single core Clarabel's per-problem loop uses); on a shared 2-core
machine a second torch thread competes with other processes and can make things slower, not faster.
Reference: Clarabel through its Python API per problem, min 1/2 x^T M x + q^T x s.t. x >= 0 (the KKT conditions of
this QP are the LCP), matrix setup (SciPy CSC of triu(M), the constraint -I x <= 0) included, default settings
(its residual is reported as it comes: at default tolerances a few near-degenerate problems stay above 1e-6).
Clarabel is timed on the first ``--clarabel-subset`` problems and its time per problem extrapolated to B: the
problems are i.i.d., so the per-problem cost does not depend on which ones are timed. The ratio is
(torchhand problems/s) / (Clarabel problems/s) in wall time; ``ratio_cpu`` is the same ratio in process CPU time
(``cpu_s``, for B problems), which other processes on a shared machine do not distort. Residuals
||min(x, Mx + q)||_inf are reported for both.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

from torchhand.kernels.lcp import solve_lcp_pgs  # noqa: E402
from torchhand.kernels.status import SolverStatus  # noqa: E402
from torchhand.solvers.lcp import random_lcp  # noqa: E402

TOL = 1e-6
VARIANTS = {"pgs": dict(omega=1.0, check_every=5), "sor1.2": dict(omega=1.2, check_every=5),
            "sor1.2 mixed": dict(omega=1.2, check_every=5, mixed=True),
            "pgs+sm": dict(subspace=True, check_every=10)}
COLUMNS = ["name", "kind", "device", "dtype", "B", "n", "threads", "median_s", "iqr_s", "per_s", "ratio", "cpu_s",
           "ratio_cpu", "res_max", "res_median", "converged", "sweeps_mean", "sweeps_max"]


def cpu_time(fn, repeats: int) -> float:
    """Median process CPU seconds per call (all threads): robust to other processes sharing the cores, and for a
    single thread what the call would take on a core of its own."""
    samples = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        samples.append(time.process_time() - t0)
    return statistics.median(samples)


def clarabel_solve_all(M: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Solve LCP(M_b, q_b) for every b as the QP min 1/2 x^T M x + q^T x, x >= 0 with Clarabel (setup included)."""
    import clarabel
    import scipy.sparse as sp

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    n = q.shape[1]
    A = sp.csc_matrix(-np.eye(n))
    b = np.zeros(n)
    cones = [clarabel.NonnegativeConeT(n)]
    xs = np.zeros_like(q)
    for k in range(q.shape[0]):
        P = sp.csc_matrix(np.triu(M[k]))
        sol = clarabel.DefaultSolver(P, q[k], A, b, cones, settings).solve()
        xs[k] = sol.x
    return xs


def _residual(M: np.ndarray, q: np.ndarray, x: np.ndarray) -> np.ndarray:
    w = np.einsum("bij,bj->bi", M, x) + q
    return np.abs(np.minimum(x, w)).max(-1)


def bench_pgs(device: str = "cpu", dtype: torch.dtype = torch.float64, B: int = 4096, n: int = 30,
              repeats: int = 5, kind: str = "pd", clarabel_subset: int = 256, seed: int = 0,
              max_iters: int = 20000) -> list[dict]:
    """Time the PGS variants on B problems and Clarabel on a subset; one row per solver (Clarabel's last)."""
    gen = torch.Generator().manual_seed(seed)
    M, q, _ = random_lcp(B, n, generator=gen, kind=kind, dtype=dtype, device=device)
    base = {"kind": kind, "device": device, "dtype": str(dtype).replace("torch.", ""), "B": B, "n": n,
            "threads": torch.get_num_threads()}
    rows = []
    for name, kw in VARIANTS.items():
        out = solve_lcp_pgs(M, q, tol=TOL, max_iters=max_iters, **kw)
        run = lambda kw=kw: solve_lcp_pgs(M, q, tol=TOL, max_iters=max_iters, **kw)   # noqa: E731
        t = time_fn(run, device, repeats=repeats, warmup=1)
        cpu = cpu_time(run, repeats) if device == "cpu" else float("nan")
        res = out.residual.double().cpu()
        rows.append({"name": f"torchhand {name}", **base, **t, "per_s": B / t["median_s"], "cpu_s": cpu,
                     "res_max": float(res.max()), "res_median": float(res.median()),
                     "converged": float((out.status == int(SolverStatus.CONVERGED)).double().mean()),
                     "sweeps_mean": float(out.iterations.double().mean()), "sweeps_max": int(out.iterations.max())})
    k = min(clarabel_subset, B)
    Mn, qn = M[:k].double().cpu().numpy(), q[:k].double().cpu().numpy()
    xs = clarabel_solve_all(Mn, qn)
    t = time_fn(lambda: clarabel_solve_all(Mn, qn), "cpu", repeats=max(1, min(repeats, 3)), warmup=0)
    cpu = cpu_time(lambda: clarabel_solve_all(Mn, qn), max(1, min(repeats, 3))) / k * B
    per_problem = t["median_s"] / k
    res = _residual(Mn, qn, np.maximum(xs, 0))
    ref = {"name": f"clarabel per problem (timed on {k}, x{B / k:g})", **base, "device": "cpu",
           "dtype": "float64", "threads": 1, "median_s": per_problem * B, "iqr_s": t["iqr_s"] / k * B,
           "per_s": 1.0 / per_problem, "cpu_s": cpu, "res_max": float(res.max()), "res_median": float(np.median(res)),
           "converged": float("nan"), "sweeps_mean": None, "sweeps_max": None, "ratio": 1.0, "ratio_cpu": 1.0}
    for r in rows:
        r["ratio"] = r["per_s"] / ref["per_s"]
        r["ratio_cpu"] = ref["cpu_s"] / r["cpu_s"]
    return rows + [ref]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--dtype", default="float64", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, default=4096)
    p.add_argument("--n", type=int, default=30)
    p.add_argument("--kinds", nargs="+", default=["pd"], choices=["pd", "psd"])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")
    p.add_argument("--clarabel-subset", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    dtype = getattr(torch, a.dtype)
    out = {"machine": machine(), "command": " ".join(sys.argv), "tol": TOL, "rows": []}
    print(f"machine: {out['machine']}")
    for kind in a.kinds:
        rows = bench_pgs(a.device, dtype, a.batch, a.n, a.repeats, kind=kind, clarabel_subset=a.clarabel_subset,
                         seed=a.seed)
        print(f"\n[lcp {kind}] B={a.batch} n={a.n}, PGS tol {TOL:g}; Clarabel timed on a subset and extrapolated")
        print_table(rows, COLUMNS)
        out["rows"] += rows
    if a.json:
        write_json(a.json, out)
        print(f"\nwrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
