"""Friction-cone solver throughput and accuracy against Clarabel called per problem (reference in the same process).

Problems: ``tests/kernels/cone_problems.py`` (the tests' builder): random grasps of spheres and boxes with 2..K
contacts, a gravity + inertia wrench, and a share built to be infeasible; many small grasps are infeasible too, so
the batch mixes both classes. The benchmark set is a *child* batch, each problem a perturbation of a *parent*
problem (contact points moved ~1 mm, wrench ~1 %), so the warm-started run starts from the parents' forces as a
search would. Rows:

* ``torchhand cold`` / ``torchhand warm``: one batched call on all B problems (median of ``repeats``, the device
  synchronised inside the timed region);
* ``clarabel``: Clarabel's Python API per problem (sparse matrices and solver object built for every problem),
  timed on the first ``n_ref`` problems and extrapolated to B (median of the per-problem time over repeats).

Accuracy is measured against Clarabel on all B problems (one untimed pass): classification agreement (ours
CONVERGED = feasible, INFEASIBLE = infeasible, MAX_ITERATIONS counts as a disagreement) over the problems Clarabel
decides, and the largest relative objective error over the problems both call feasible.

    python scripts/bench_cone.py --device cpu --dtype float64 --batch 4096 --json bench_cone.json
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests", "kernels"))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402
from cone_problems import clarabel_solve, perturb_problems, random_cone_problems  # noqa: E402

from torchhand.kernels.friction_cone import solve_friction_cone  # noqa: E402
from torchhand.kernels.status import SolverStatus  # noqa: E402

COLUMNS = ["name", "device", "dtype", "B", "median_s", "iqr_s", "problems_per_s", "ratio", "mean_iters",
           "agreement", "undecided", "obj_max_rel_err"]


def _numpy_problems(problems: dict) -> list[dict]:
    arrays = {k: (v.detach().cpu().double().numpy() if v is not None and v.is_floating_point() else
                  (v.cpu().numpy() if v is not None else None)) for k, v in problems.items()}
    B = arrays["points"].shape[0]
    return [{k: (v[b] if v is not None else None) for k, v in arrays.items()} for b in range(B)]


def _accuracy(res, ref: list[dict]) -> dict:
    status = res.status.cpu().tolist()
    objective = res.objective.detach().cpu().double().tolist()
    decided = [i for i, r in enumerate(ref) if r["status"] in ("feasible", "infeasible")]
    ours = {int(SolverStatus.CONVERGED): "feasible", int(SolverStatus.INFEASIBLE): "infeasible"}
    agree = sum(ours.get(status[i]) == ref[i]["status"] for i in decided)
    both = [i for i in decided if ref[i]["status"] == "feasible" and status[i] == int(SolverStatus.CONVERGED)]
    rel = [abs(objective[i] - ref[i]["objective"]) / max(abs(ref[i]["objective"]), 1e-12) for i in both]
    return {"agreement": agree / max(len(decided), 1), "decided": len(decided),
            "undecided": sum(status[i] == int(SolverStatus.MAX_ITERATIONS) for i in decided),
            "obj_max_rel_err": max(rel) if rel else float("nan"),
            "obj_median_rel_err": float(np.median(rel)) if rel else float("nan"),
            "reference_feasible_frac": sum(ref[i]["status"] == "feasible" for i in decided) / max(len(decided), 1)}


def bench_cone(device: str = "cpu", dtype: torch.dtype = torch.float64, B: int = 4096, K: int = 5,
               repeats: int = 5, n_ref: int = 300, seed: int = 0) -> list[dict]:
    """Rows for our cold and warm-started batched solves and for Clarabel per problem (see the module docstring)."""
    gen = torch.Generator().manual_seed(seed)
    parents = random_cone_problems(B, K, gen, dtype=dtype, device=device)
    children = perturb_problems(parents, gen, scale=0.01)
    warm = solve_friction_cone(**parents).forces                       # a search would have these already
    dname = str(dtype).replace("torch.", "")

    ref_problems = _numpy_problems(children)
    reference = [clarabel_solve(**p) for p in ref_problems]           # untimed pass, for the accuracy figures

    def clarabel_subset():
        for p in ref_problems[:n_ref]:
            clarabel_solve(**p)

    samples = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        clarabel_subset()
        samples.append((time.perf_counter() - t0) / min(n_ref, B))
    per_problem = statistics.median(samples)
    q = statistics.quantiles(samples, n=4) if len(samples) >= 2 else [samples[0]] * 3
    ref_row = {"name": "clarabel per problem", "device": "cpu", "dtype": "float64", "B": B,
               "median_s": per_problem * B, "iqr_s": (q[2] - q[0]) * B, "problems_per_s": 1 / per_problem,
               "per_problem_ms": per_problem * 1e3, "timed_on": min(n_ref, B), "extrapolated": True}

    rows = []
    for name, ws in (("torchhand cold", None), ("torchhand warm", warm)):
        def ours(ws=ws):
            return solve_friction_cone(**children, warm_start=ws)

        t = time_fn(ours, device, repeats=repeats, warmup=1)
        res = ours()
        rows.append({"name": name, "device": device, "dtype": dname, "B": B, "K": K, **t,
                     "problems_per_s": B / t["median_s"], "ratio": ref_row["median_s"] / t["median_s"],
                     "mean_iters": float(res.iterations.double().mean()),
                     "mean_iters_feasible": float(res.iterations[res.status == 0].double().mean()),
                     **_accuracy(res, reference)})
    return rows + [ref_row]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--dtype", default="float64", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, default=4096)
    p.add_argument("--contacts", type=int, default=5)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--n-ref", type=int, default=300, help="problems on which Clarabel is timed")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: leave as is)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    rows = bench_cone(a.device, getattr(torch, a.dtype), a.batch, a.contacts, a.repeats, a.n_ref, a.seed)
    print(f"machine: {machine()}")
    print_table(rows, COLUMNS)
    for r in rows[:2]:
        print(f"{r['name']}: {r['ratio']:.1f}x Clarabel's throughput (Clarabel timed on {rows[-1]['timed_on']} "
              f"problems, extrapolated); classification agreement {100 * r['agreement']:.2f}% of "
              f"{r['decided']} ({r['undecided']} at max_iters); objective max rel. error {r['obj_max_rel_err']:.1e}; "
              f"mean iterations {r['mean_iters']:.1f} (feasible {r['mean_iters_feasible']:.1f})")
    if a.json:
        write_json(a.json, {"machine": machine(), "command": " ".join(sys.argv), "rows": rows})
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
