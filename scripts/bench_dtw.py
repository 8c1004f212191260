"""DTW benchmark: torchhand.kernels.dtw against dtaidistance (C) and tslearn (numba) in the same run.

Work per call on every side: the frame distances from the raw sequences (Euclidean for torchhand,
squared Euclidean inside the references), the DP and the warping path. torchhand is also timed on a precomputed
cost ("kernel only": ``dtw`` alone, the splicing pipeline's case, where the cost is Eq. 6). Cases:
  * one banded 569 x 569 pair (Majkowska et al.'s Directions sequence length; target < 25 ms on CPU, the paper's
    Matlab took 10.95 s for its two passes), band W = 10% of the length as in their second pass;
  * one 569 x 2276 pair (a 569-frame body clip against a 4x longer hand clip), full rows (target <= 60 ms) and
    with a 30% band read as a radius of 0.30 m columns around the slope, ``|j - (m/n) i| <= 0.3 m`` (no reference
    has Eq. 3's band for n != m: timed alone);
  * B pairs of 200 x 200, unconstrained and banded (10%): pairs per second; and the banded case on 1-D series
    against dtaidistance's 1-D C loop (``dtw.warping_path(..., include_distance=True)``, one DP per pair; target:
    ratio >= 1).
Inputs come from the tests' builder (``tests/kernels/test_dtw.py::warped_pairs``): 12-D features (4 markers x 3)
unless stated. torchhand and the references are timed alternately, one call each per round (the machine may be
busy: the ratios are the figures to read). References are skipped with a note when not installed. ``--memory``
adds the peak memory of one call on 569 x 2276 full rows (1 and B pairs), each in a fresh interpreter.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time

# Idle OpenMP threads sleep rather than spin (torchhand's CLI default): on a small or busy machine waiting threads
# slow every op (167-183 ms instead of 15-18 ms for the banded 569 x 569 pair with 2 threads on the 2-core VM).
# Effective only when this script is the entry point (before torch is imported).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "kernels"))
from _timing import machine, print_table, sync, write_json  # noqa: E402
from test_dtw import warped_pairs  # noqa: E402

from torchhand.kernels.dtw import dtw, pairwise_cost  # noqa: E402

TARGET_S = {"569x569 band 10%": 0.025, "569x2276 no band": 0.060}
COLUMNS = ["name", "device", "B", "n", "m", "band", "median_s", "iqr_s", "min_s", "pairs_per_s", "ratio",
           "ratio_kernel", "target_ok"]


def _references(x, y, radius):
    """name -> (path + distance of every pair, distances for the accuracy check), per installed reference."""
    refs = {}
    d = x.shape[-1]
    try:
        from dtaidistance import dtw as dtw_1d, dtw_ndim

        kw_d = {} if radius is None else {"window": radius + 1}        # dtaidistance: |i - j| < window
        if d == 1:                                                       # path and distance from one DP
            refs["dtaidistance (C)"] = (
                lambda: [dtw_1d.warping_path(a[:, 0], b[:, 0], include_distance=True, use_c=True, **kw_d)
                         for a, b in zip(x, y)],
                lambda out: [dist for _, dist in out])
        else:
            refs["dtaidistance (C)"] = (
                lambda: [(dtw_ndim.warping_path(a, b, use_c=True, **kw_d), dtw_ndim.distance(a, b, use_c=True, **kw_d))
                         for a, b in zip(x, y)],
                lambda out: [dist for _, dist in out])
    except ImportError:
        print("note: dtaidistance not installed, skipped")
    if d > 1:
        try:
            from tslearn.metrics import dtw_path

            kw_t = {} if radius is None else {"global_constraint": "sakoe_chiba", "sakoe_chiba_radius": radius}
            refs["tslearn (numba)"] = (lambda: [dtw_path(a, b, **kw_t) for a, b in zip(x, y)],
                                       lambda out: [dist for _, dist in out])
        except ImportError:
            print("note: tslearn not installed, skipped")
    return refs


def _alternate(fns: dict, device: str, repeats: int, warmup: int = 1) -> dict:
    """Median, spread and min of the seconds per call of each function, calling them in turn, one call per round."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    samples = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            sync(device)
            t0 = time.perf_counter()
            fn()
            sync(device)
            samples[name].append(time.perf_counter() - t0)
    out = {}
    for name, s in samples.items():
        q = statistics.quantiles(s, n=4) if len(s) >= 2 else [s[0]] * 3
        out[name] = {"median_s": statistics.median(s), "min_s": min(s), "max_s": max(s), "iqr_s": q[2] - q[0],
                     "repeats": repeats}
    return out


def _case(label, B, n, m, d, device, dtype, repeats, gen, band_fraction, reference=True):
    x, y = warped_pairs(B, n, m, d, gen, dtype=dtype, device=device)
    if band_fraction is None:
        radius, W = None, None
    elif n == m:
        radius = int(band_fraction * n)
        W = (radius + 0.5) / math.sqrt(2.0)                             # n = m: |i - j| <= radius, as the references
    else:
        radius, W = None, band_fraction * m * n / math.sqrt(n * n + m * m)    # |j - (m/n) i| <= fraction * m
    cost = pairwise_cost(x, y)

    def ours():
        return dtw(pairwise_cost(x, y), band=W)

    def kernel():
        return dtw(cost, band=W)

    res = ours()
    if not bool((res.status == 0).all()):
        raise RuntimeError(f"{label}: dtw did not find a path for every pair")
    xn, yn = x.double().cpu().numpy(), y.double().cpu().numpy()
    refs = _references(xn, yn, radius) if reference and (band_fraction is None or n == m) else {}
    fns = {"ours": ours, "kernel": kernel}
    diffs = {}
    if refs:     # the references' distance is sqrt(sum of squared frame distances along the path)
        ours_sq = dtw(pairwise_cost(x.double(), y.double(), squared=True), band=W).distance.sqrt().cpu().tolist()
    for name, (fn, distances) in refs.items():
        d_ref = distances(fn())
        diffs[name] = max(abs(o - r) / max(r, 1e-12) for o, r in zip(ours_sq, d_ref))
        fns[name] = fn
    t = _alternate(fns, device, repeats)
    band = None if band_fraction is None else f"{band_fraction:.0%}"
    mine = {"name": f"torchhand {label}", "device": device, "B": B, "n": n, "m": m, "band": band, **t["ours"],
            "pairs_per_s": B / t["ours"]["median_s"], "kernel_median_s": t["kernel"]["median_s"]}
    if label in TARGET_S:
        mine["target_ok"] = t["ours"]["median_s"] < TARGET_S[label]
    rows = [mine]
    for name in refs:
        tr = t[name]
        rows.append({"name": name, "device": "cpu", "B": B, "n": n, "m": m, "band": band, **tr,
                     "pairs_per_s": B / tr["median_s"],
                     "ratio": tr["median_s"] / t["ours"]["median_s"],          # reference / ours: > 1 = ours faster
                     "ratio_kernel": tr["median_s"] / t["kernel"]["median_s"],  # the same against dtw alone
                     "max_rel_diff": diffs[name]})
    return rows


_MEMORY_PROBE = """
import json, sys, torch
from torchhand.kernels.dtw import dtw
B, n, m, dtype = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), getattr(torch, sys.argv[4])
def status(key):
    return next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith(key)) / 1024
cost = torch.rand(B, n, m, generator=torch.Generator().manual_seed(0), dtype=dtype)
dtw(cost[:1, :8, :8])
before = status("VmRSS")
open("/proc/self/clear_refs", "w").write("5")                  # resets VmHWM (peak RSS)
res = dtw(cost)
print(json.dumps({"cost_mib": cost.numel() * cost.element_size() / 2**20, "peak_minus_before_mib":
                  status("VmHWM") - before, "converged": bool((res.status == 0).all())}))
"""


def peak_memory(B: int, n: int, m: int, dtype: str = "float64") -> dict:
    """Peak resident memory that one ``dtw`` call on random full-row costs (B, n, m) adds, in MiB: VmHWM minus VmRSS
    before the call, in a fresh interpreter (Linux only; torch's CPU allocator keeps no statistics)."""
    out = subprocess.run([sys.executable, "-c", _MEMORY_PROBE, str(B), str(n), str(m), dtype], check=True,
                         capture_output=True, text=True)
    return {"name": f"peak memory {B}x {n}x{m} no band", "B": B, "n": n, "m": m, "dtype": dtype,
            **json.loads(out.stdout.strip().splitlines()[-1])}


def bench_dtw(device: str = "cpu", repeats: int = 7, batch: int = 64, dtype=torch.float32) -> list[dict]:
    """Rows of timings (median/IQR/min seconds per call, pairs per second) for torchhand and the references.

    ``ratio`` on a reference row = reference seconds / torchhand seconds for the same work (> 1: torchhand faster);
    ``ratio_kernel`` compares with ``dtw`` alone on a precomputed cost (``kernel_median_s`` on torchhand's row).
    """
    gen = torch.Generator().manual_seed(0)
    rows = []
    rows += _case("569x569 band 10%", 1, 569, 569, 12, device, dtype, repeats, gen, 0.10)
    rows += _case("569x569 no band", 1, 569, 569, 12, device, dtype, repeats, gen, None)
    rows += _case("569x2276 no band", 1, 569, 2276, 12, device, dtype, repeats, gen, None)
    rows += _case("569x2276 band 30%", 1, 569, 2276, 12, device, dtype, repeats, gen, 0.30)
    rows += _case(f"{batch}x 200x200 no band", batch, 200, 200, 12, device, dtype, repeats, gen, None)
    rows += _case(f"{batch}x 200x200 band 10%", batch, 200, 200, 12, device, dtype, repeats, gen, 0.10)
    rows += _case(f"{batch}x 200x200 band 10%, 1-D", batch, 200, 200, 1, device, dtype, repeats, gen, 0.10)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's choice)")
    p.add_argument("--json", help="write the results here (atomically)")
    p.add_argument("--memory", action="store_true", help="also measure the peak memory of B = 1 and B = --batch "
                   "pairs of 569 x 2276 full rows (CPU, Linux)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    rows = bench_dtw(a.device, a.repeats, a.batch, getattr(torch, a.dtype))
    info = machine()
    print(f"machine: {info}")
    print_table(rows, COLUMNS + ["kernel_median_s", "max_rel_diff"])
    if a.memory:
        memory = [peak_memory(B, 569, 2276, a.dtype) for B in (1, a.batch)]
        print_table(memory, ["name", "dtype", "cost_mib", "peak_minus_before_mib", "converged"])
        rows += memory
    for r in rows:
        if "target_ok" in r:
            label = r["name"].removeprefix("torchhand ")
            print(f"{label} incl. cost and path: {r['median_s'] * 1e3:.1f} ms median (target < "
                  f"{TARGET_S[label] * 1e3:.0f} ms: {'met' if r['target_ok'] else 'NOT met'})")
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "rows": rows})
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
