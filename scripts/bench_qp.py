"""QP benchmarks: the batched QP kernel and torchhand.solvers._qpth (qpth) against Clarabel called per problem, same run.

Suite ``window`` (the default): Liu 2009 window QPs (Eq. 4, n = 6 frames) built by
``tests/kernels/test_force_plan.py::window_problems`` and ``torchhand.kernels.force_plan.assemble_window_qp``:
72 variables (3 hand contacts), 168 (3 hand + 4 table contacts) and 312 (5 hand + 8 table contacts), randomized box
grasps along smooth trajectories (some infeasible, as they come), float64, batch sizes 1 and 64. Rows:
``torchhand.kernels.convex_qp.solve_convex_qp`` (interior point, then ADMM for undecided problems),
``torchhand.solvers._dense.solve_qp_dense`` (the same interior point and polish in NumPy / LAPACK, one problem at a time;
rows at B = 1 by default, ``--dense-max-batch``),
``torchhand.solvers._qpth.solve_qp`` (qpth, ``ridge`` 1e-8 since Q is only PSD) and Clarabel per problem with its set-up
inside the timed region. ``speedup_vs_clarabel`` and
``speedup_vs_qpth`` are ratios of medians in this run; ``max_rel_obj_diff`` is |obj - obj_clarabel| /
max(1, |obj_clarabel|) over the problems both solved; ``status_agreement`` compares solved / not solved.

Suite ``random`` (the older rows):
Problems: B random strictly convex QPs of the size of Liu 2009's force-planning step (12 variables = 3 contacts x
4 pyramid coefficients, 24 inequality rows, 6 equality rows = the object's wrench), 2% of them built infeasible,
from the tests' builder (``tests/torchhand/test_qp.py::random_qps``). Clarabel gets each problem through its
Python API with the matrix set-up inside the timed region. Accuracy: objective relative to Clarabel's on the
problems both solve, and agreement of the solved / infeasible classification. The LP feasibility rows compare
:func:`torchhand.solvers._qpth.lp_feasible` with Clarabel solving the same constraints with a zero objective.
"""

from __future__ import annotations

import argparse
import importlib.util
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
from torchhand.solvers._qpth import lp_feasible, solve_qp  # noqa: E402

_HAS_QPTH = importlib.util.find_spec("qpth") is not None

COLUMNS = ["name", "device", "dtype", "B", "median_s", "iqr_s", "problems_per_s", "speedup", "max_rel_obj_diff",
           "status_agreement", "converged"]
WINDOW_COLUMNS = ["name", "nz", "B", "device", "median_s", "iqr_s", "repeats", "ms_per_problem",
                  "speedup_vs_clarabel", "speedup_vs_qpth", "max_rel_obj_diff", "status_agreement", "converged"]
WINDOW_CASES = {72: dict(hand_slots=3, table=False), 168: dict(hand_slots=3, table=True),
                312: dict(hand_slots=5, table=True, table_slots=8)}
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
    method = "qpth" if _HAS_QPTH else "admm"
    feas = lp_feasible(G, h, A, b, method=method)
    t_lp = time_fn(lambda: lp_feasible(G, h, A, b, method=method), device, repeats, warmup=1)
    rows.append({"name": f"torchhand lp_feasible ({method})", "device": device, "dtype": "float64", "B": B, **t_lp,
                 "problems_per_s": B / t_lp["median_s"], "speedup": t_lp_ref["median_s"] / t_lp["median_s"],
                 "status_agreement": float(np.mean(feas.feasible.cpu().numpy() == lp_ref)),
                 "converged": int(feas.feasible.sum())})
    return rows


def bench_window_qp(device: str = "cpu", sizes=(72, 168, 312), batches=(1, 64), repeats: int = 5,
                    qpth_repeats: int | None = None, seed: int = 0, dense_max_batch: int = 1) -> list[dict]:
    """Rows per (size, batch): ADMM kernel, the dense path (B <= ``dense_max_batch``, CPU), qpth adapter, Clarabel
    per problem (see the module docstring)."""
    sys.path.insert(0, os.path.join(HERE, "..", "tests", "kernels"))
    from test_force_plan import window_problems

    from torchhand.solvers._dense import solve_qp_dense
    from torchhand.kernels.convex_qp import solve_convex_qp
    from torchhand.kernels.force_plan import assemble_window_qp

    qpth_repeats = repeats if qpth_repeats is None else qpth_repeats
    conv = int(SolverStatus.CONVERGED)
    rows = []
    for nz in sizes:
        for B in batches:
            gen = torch.Generator().manual_seed(seed + nz + B)
            qp = assemble_window_qp(**window_problems(B, gen, **WINDOW_CASES[nz]))
            assert qp.Q.shape[-1] == nz
            prob = {k: getattr(qp, k) for k in ("Q", "p", "G", "h", "A", "b")}
            ref_run = _clarabel_all(prob)
            ref = ref_run()
            t_ref = time_fn(ref_run, "cpu", repeats, warmup=0)
            ref_ok = np.array([st == "Solved" for _, _, st in ref])
            ref_obj = np.array([o if st == "Solved" else np.nan for _, o, st in ref])
            base = {"nz": nz, "B": B}
            rows.append({"name": "clarabel per problem (set-up incl.)", **base, "device": "cpu", **t_ref,
                         "ms_per_problem": 1e3 * t_ref["median_s"] / B, "converged": int(ref_ok.sum())})
            args = {k: v.to(device) for k, v in prob.items()}
            runs = [("kernel solve_convex_qp (ipm+admm)", lambda: solve_convex_qp(**args), repeats)]
            if B <= dense_max_batch and device == "cpu":
                runs.append(("dense torchhand.solvers._dense.solve_qp_dense", lambda: solve_qp_dense(**args), repeats))
            if _HAS_QPTH:            # the optional extra torchhand[qpth]; without it its rows are left out
                runs.append(("qpth torchhand.solvers._qpth.solve_qp", lambda: solve_qp(**args, ridge=1e-8),
                             qpth_repeats))
            t_qpth, first = None, len(rows)
            for name, fn, reps in runs:
                res = fn()
                t = time_fn(fn, device, reps, warmup=0)
                st = res.status.cpu().numpy()
                ok = (st == conv) & ref_ok
                obj = res.objective.double().cpu().numpy()
                rel = np.abs(obj[ok] - ref_obj[ok]) / np.maximum(1.0, np.abs(ref_obj[ok]))
                row = {"name": name, **base, "device": device, **t, "ms_per_problem": 1e3 * t["median_s"] / B,
                       "speedup_vs_clarabel": t_ref["median_s"] / t["median_s"],
                       "max_rel_obj_diff": float(rel.max()) if rel.size else None,
                       "status_agreement": float(np.mean((st == conv) == ref_ok)), "converged": int((st == conv).sum())}
                rows.append(row)
                if name.startswith("qpth"):
                    t_qpth = t["median_s"]
            for row in rows[first:-1] if t_qpth is not None else ():
                row["speedup_vs_qpth"] = t_qpth / row["median_s"]
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--suite", choices=("window", "random", "all"), default="window")
    p.add_argument("--batch", type=int, default=1024, help="batch of the random suite")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--qpth-repeats", type=int, default=None, help="repeats of the qpth rows (default: --repeats)")
    p.add_argument("--sizes", type=int, nargs="+", default=[72, 168, 312], choices=sorted(WINDOW_CASES))
    p.add_argument("--batches", type=int, nargs="+", default=[1, 64])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dense-max-batch", type=int, default=1, help="largest B with a method=dense row (CPU)")
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's choice)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    info = machine()
    print(f"machine: {info}")
    rows = []
    if a.suite in ("window", "all"):
        w = bench_window_qp(a.device, a.sizes, a.batches, a.repeats, a.qpth_repeats, a.seed, a.dense_max_batch)
        print_table(w, WINDOW_COLUMNS)
        rows += w
    if a.suite in ("random", "all"):
        r = bench_qp(a.device, a.batch, a.repeats)
        print_table(r, COLUMNS)
        rows += r
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "rows": rows})
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
