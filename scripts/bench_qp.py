"""QP adapter benchmark: torchhand.qp (qpth underneath) against Clarabel called per problem, same run.

Problems: B random strictly convex QPs of the size of Liu 2009's force-planning step (12 variables = 3 contacts x
4 pyramid coefficients, 24 inequality rows, 6 equality rows = the object's wrench), 2% of them built infeasible,
from the tests' builder (``tests/torchhand/test_qp.py::random_qps``). Clarabel gets each problem through its
Python API with the matrix set-up inside the timed region. Accuracy: objective relative to Clarabel's on the
problems both solve, and agreement of the solved / infeasible classification. The LP feasibility rows compare
:func:`torchhand.qp.lp_feasible` with Clarabel solving the same constraints with a zero objective.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "torchhand"))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402
from test_qp import clarabel_qp, random_qps  # noqa: E402

from torchhand.kernels.status import SolverStatus  # noqa: E402
from torchhand.qp import lp_feasible, solve_qp  # noqa: E402

COLUMNS = ["name", "device", "dtype", "B", "median_s", "iqr_s", "problems_per_s", "speedup", "max_rel_obj_diff",
           "status_agreement", "converged"]
NZ, NINEQ, NEQ = 12, 24, 6


def _clarabel_all(prob: dict, lp: bool = False):
    names = ("Q", "p", "G", "h", "A", "b")
    arrs = {k: prob[k].double().cpu().numpy() for k in names}
    B, nz = arrs["p"].shape

    def run():
        out = []
        for i in range(B):
            Q = np.zeros((nz, nz)) if lp else arrs["Q"][i]
            p = np.zeros(nz) if lp else arrs["p"][i]
            out.append(clarabel_qp(Q, p, arrs["G"][i], arrs["h"][i], arrs["A"][i], arrs["b"][i]))
        return out

    return run


def bench_qp(device: str = "cpu", B: int = 1024, repeats: int = 3) -> list[dict]:
    """Rows: torchhand solve_qp (float64, float32), Clarabel per problem, lp_feasible vs Clarabel LPs.

    ``speedup`` = Clarabel seconds / torchhand seconds for the same B problems.
    """
    gen = torch.Generator().manual_seed(0)
    bad = list(range(0, B, 50))
    prob = random_qps(B, NZ, NINEQ, NEQ, gen, infeasible=bad)
    ref_run = _clarabel_all(prob)
    ref = ref_run()
    t_ref = time_fn(ref_run, "cpu", repeats, warmup=0)
    ref_solved = np.array([st == "Solved" for _, _, st in ref])
    ref_obj = np.array([obj if st == "Solved" else np.nan for _, obj, st in ref])
    rows = [{"name": "clarabel per problem (set-up incl.)", "device": "cpu", "dtype": "float64", "B": B, **t_ref,
             "problems_per_s": B / t_ref["median_s"], "converged": int(ref_solved.sum())}]
    for dtype in (torch.float64, torch.float32):
        args = {k: v.to(device=device, dtype=dtype) for k, v in prob.items()}
        res = solve_qp(**args)
        t = time_fn(lambda: solve_qp(**args), device, repeats, warmup=1)
        st = res.status.cpu().numpy()
        ok = (st == int(SolverStatus.CONVERGED)) & ref_solved
        obj = res.objective.double().cpu().numpy()
        rel = np.abs(obj[ok] - ref_obj[ok]) / np.maximum(1.0, np.abs(ref_obj[ok]))
        agree = np.mean((st == int(SolverStatus.CONVERGED)) == ref_solved)
        rows.append({"name": "torchhand solve_qp (qpth)", "device": device, "dtype": str(dtype).split(".")[-1],
                     "B": B, **t, "problems_per_s": B / t["median_s"], "speedup": t_ref["median_s"] / t["median_s"],
                     "max_rel_obj_diff": float(rel.max()) if rel.size else None, "status_agreement": float(agree),
                     "converged": int((st == int(SolverStatus.CONVERGED)).sum())})
    # LP feasibility of the same constraint sets (Liu's additional-contacts test).
    lp_run = _clarabel_all(prob, lp=True)
    lp_ref = np.array([st == "Solved" for _, _, st in lp_run()])
    t_lp_ref = time_fn(lp_run, "cpu", repeats, warmup=0)
    rows.append({"name": "clarabel LP feasibility per problem", "device": "cpu", "dtype": "float64", "B": B,
                 **t_lp_ref, "problems_per_s": B / t_lp_ref["median_s"], "converged": int(lp_ref.sum())})
    G, h, A, b = (prob[k].to(device) for k in ("G", "h", "A", "b"))
    feas = lp_feasible(G, h, A, b)
    t_lp = time_fn(lambda: lp_feasible(G, h, A, b), device, repeats, warmup=1)
    rows.append({"name": "torchhand lp_feasible (phase-1 QP)", "device": device, "dtype": "float64", "B": B, **t_lp,
                 "problems_per_s": B / t_lp["median_s"], "speedup": t_lp_ref["median_s"] / t_lp["median_s"],
                 "status_agreement": float(np.mean(feas.feasible.cpu().numpy() == lp_ref)),
                 "converged": int(feas.feasible.sum())})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's choice)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    rows = bench_qp(a.device, a.batch, a.repeats)
    info = machine()
    print(f"machine: {info}")
    print_table(rows, COLUMNS)
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "rows": rows})
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
