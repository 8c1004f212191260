"""DTW benchmark: torchhand.kernels.dtw against dtaidistance (C) and tslearn (numba) in the same run.

Work per call on every side: the frame distances from the raw sequences (Euclidean for torchhand,
squared Euclidean inside the references), the DP and the warping path.
  * one banded 569 x 569 pair (Majkowska et al.'s Directions sequence length; target < 25 ms on CPU, the paper's
    Matlab took 10.95 s for its two passes), band W = 10% of the length as in their second pass;
  * B pairs of 200 x 200, unconstrained and banded: pairs per second.
Inputs come from the tests' builder (``tests/kernels/test_dtw.py::warped_pairs``): 12-D features (4 markers x 3).
References are skipped with a note when not installed.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "kernels"))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402
from test_dtw import warped_pairs  # noqa: E402

from torchhand.kernels.dtw import dtw, pairwise_cost  # noqa: E402

TARGET_S = 0.025
COLUMNS = ["name", "device", "B", "n", "band", "median_s", "iqr_s", "min_s", "pairs_per_s", "ratio", "target_ok"]


def _references(x, y, radius):
    """name -> (path + distance of every pair, distances for the accuracy check), per installed reference."""
    refs = {}
    try:
        from dtaidistance import dtw_ndim

        kw_d = {} if radius is None else {"window": radius + 1}        # dtaidistance: |i - j| < window
        refs["dtaidistance (C)"] = (
            lambda: [(dtw_ndim.warping_path(a, b, use_c=True, **kw_d), dtw_ndim.distance(a, b, use_c=True, **kw_d))
                     for a, b in zip(x, y)],
            lambda out: [d for _, d in out])
    except ImportError:
        pass
    try:
        from tslearn.metrics import dtw_path

        kw_t = {} if radius is None else {"global_constraint": "sakoe_chiba", "sakoe_chiba_radius": radius}
        refs["tslearn (numba)"] = (lambda: [dtw_path(a, b, **kw_t) for a, b in zip(x, y)],
                                   lambda out: [d for _, d in out])
    except ImportError:
        pass
    return refs


def _case(label, B, n, device, dtype, repeats, gen, band_fraction):
    x, y = warped_pairs(B, n, n, 12, gen, dtype=dtype, device=device)
    radius = None if band_fraction is None else int(band_fraction * n)
    W = None if radius is None else (radius + 0.5) / math.sqrt(2.0)      # n = m: |i - j| <= radius, as the references

    def ours():
        return dtw(pairwise_cost(x, y), band=W)

    res = ours()
    if not bool((res.status == 0).all()):
        raise RuntimeError(f"{label}: dtw did not find a path for every pair")
    t = time_fn(ours, device, repeats)
    mine = {"name": f"torchhand {label}", "device": device, "B": B, "n": n, "band": radius, **t,
            "pairs_per_s": B / t["median_s"]}
    if B == 1:
        mine["target_ok"] = t["median_s"] < TARGET_S
    rows = [mine]
    # The references' distance is sqrt(sum of squared frame distances along the path).
    ours_sq = dtw(pairwise_cost(x.double(), y.double(), squared=True), band=W).distance.sqrt().cpu().tolist()
    xn, yn = x.double().cpu().numpy(), y.double().cpu().numpy()
    for name, (fn, distances) in _references(xn, yn, radius).items():
        d_ref = distances(fn())
        tr = time_fn(fn, "cpu", max(3, repeats // 2), warmup=1)
        rows.append({"name": name, "device": "cpu", "B": B, "n": n, "band": radius, **tr,
                     "pairs_per_s": B / tr["median_s"],
                     "ratio": tr["median_s"] / t["median_s"],           # reference time / ours: > 1 = torchhand faster
                     "max_rel_diff": max(abs(o - d) / max(d, 1e-12) for o, d in zip(ours_sq, d_ref))})
    return rows


def bench_dtw(device: str = "cpu", repeats: int = 7, batch: int = 64, dtype=torch.float32) -> list[dict]:
    """Rows of timings (median/IQR/min seconds per call, pairs per second) for torchhand and the references.

    ``ratio`` on a reference row = reference seconds / torchhand seconds for the same work (> 1: torchhand faster).
    """
    gen = torch.Generator().manual_seed(0)
    rows = []
    rows += _case("569x569 band 10%", 1, 569, device, dtype, repeats, gen, 0.10)
    rows += _case("569x569 no band", 1, 569, device, dtype, repeats, gen, None)
    rows += _case(f"{batch}x 200x200 no band", batch, 200, device, dtype, repeats, gen, None)
    rows += _case(f"{batch}x 200x200 band 10%", batch, 200, device, dtype, repeats, gen, 0.10)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's choice)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    rows = bench_dtw(a.device, a.repeats, a.batch, getattr(torch, a.dtype))
    info = machine()
    print(f"machine: {info}")
    print_table(rows, COLUMNS + ["max_rel_diff"])
    single = rows[0]
    print(f"\none banded 569x569 pair incl. path: {single['median_s'] * 1e3:.1f} ms median "
          f"(target < {TARGET_S * 1e3:.0f} ms: {'met' if single['target_ok'] else 'NOT met'})")
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "rows": rows})
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
