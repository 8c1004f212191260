"""torchhand benchmarks: ``python scripts/bench.py [fk|sdf|all] [--device cpu|cuda] [--json OUT]``.

Each suite runs its reference in the same process so the figure that matters is a ratio:
  fk   FK of all links + Jacobian of the five fingertips, torchhand vs pytorch_kinematics (same hand, exported MJCF)
  sdf  SDF grid trilinear queries vs trimesh's exact signed distance
  kernels  friction-cone solver vs Clarabel, PGS LCP vs Clarabel (as QPs), DTW vs dtaidistance/tslearn,
           the qpth adapter vs Clarabel
Medians of several runs with their spread; results as a table, and as JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import os
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import machine, print_table, write_json  # noqa: E402

SUITES = ("fk", "sdf", "kernels")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("suite", nargs="?", default="all", choices=SUITES + ("all",))
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 64, 4096, 65536])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    dtype = getattr(torch, a.dtype)
    suites = SUITES if a.suite == "all" else (a.suite,)
    out = {"machine": machine(), "command": " ".join(sys.argv), "suites": {}}
    print(f"machine: {out['machine']}")
    if "fk" in suites:
        from bench_fk import bench_fk, check_against_reference

        print(f"\n[fk] agreement with pytorch_kinematics (float64, max |T| difference): {check_against_reference():.2e}")
        rows = bench_fk(a.device, dtype, a.batch, a.repeats)
        print_table(rows, ["name", "device", "dtype", "B", "median_s", "iqr_s", "per_s", "ratio"])
        out["suites"]["fk"] = rows
    if "sdf" in suites:
        from bench_sdf import bench_sdf, bench_trimesh_reference

        rows = bench_sdf(a.device, dtype, a.batch, repeats=a.repeats)
        ref = bench_trimesh_reference()
        print("\n[sdf]")
        print_table(rows + [ref], ["name", "device", "dtype", "B", "points", "median_s", "spread_s", "points_per_s"])
        best = max(r["points_per_s"] for r in rows)
        print(f"grid query / trimesh exact: {best / ref['points_per_s']:.0f}x")
        out["suites"]["sdf"] = rows + [ref]
    if "kernels" in suites:
        out["suites"]["kernels"] = {}
        for name, module, fn, kwargs in (
            ("friction_cone", "bench_cone", "bench_cone", {"device": a.device}),
            ("pgs", "bench_lcp", "bench_pgs", {"device": a.device}),
            ("dtw", "bench_dtw", "bench_dtw", {"device": a.device}),
            ("qp", "bench_qp", "bench_qp", {"device": a.device}),
        ):
            rows = getattr(__import__(module), fn)(**kwargs)
            print(f"\n[kernels: {name}]")
            print_table(rows, _columns(rows))
            out["suites"]["kernels"][name] = rows
    if a.json:
        write_json(a.json, out)
        print(f"\nwrote {a.json}")
    return 0


def _columns(rows: list[dict]) -> list[str]:
    """Union of the rows' keys in first-seen order, leaving out nested values."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k, v in r.items() if k not in cols and not isinstance(v, (dict, list))]
    return cols


if __name__ == "__main__":
    sys.exit(main())
