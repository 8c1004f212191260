"""Threads and load: ``torchhand synthesize`` with a node budget, alone and beside a CPU-heavy process.

For each thread count in ``--threads`` the script runs the same synthesis (scene, seed, ``--max-nodes``) twice:
alone, and while ``--hogs`` busy processes (numpy matrix products, one thread each) load the machine. It reports
the wall time of each run, the ratio loaded / alone, and whether the solution arrays of the two runs are
byte-identical (same seed and thread count: they must be). A second table compares ``OMP_WAIT_POLICY``
settings under load when ``--wait-policy`` is given.

    python scripts/bench_threads.py --scene box-turn --max-nodes 6000 --threads 1 2 --json out/threads.json

Numbers depend on the machine; the ratios are what to compare (BENCHMARKS.md, "Threads").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _hog(stop_at: float) -> None:
    os.environ["OMP_NUM_THREADS"] = "1"
    import numpy as np

    a = np.random.default_rng(0).standard_normal((300, 300))
    while time.time() < stop_at:
        a = np.tanh(a @ a.T * 1e-3)


def _digest(out: Path) -> str:
    import numpy as np

    h = hashlib.sha256()
    for f in sorted((out / "solutions").glob("sol_*.npz")):
        with np.load(f) as z:
            for k in sorted(z.files):
                h.update(k.encode())
                h.update(np.ascontiguousarray(z[k]).tobytes())
    return h.hexdigest()[:16]


EXTRA: list = []   # more synthesize arguments (--extra)


def _run(scene: str, max_nodes: int, threads: int, seed: int, solutions: int, env_extra: dict) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        env = dict(os.environ, **env_extra)
        cmd = ["torchhand", "synthesize", scene, "--out", str(out), "--max-nodes", str(max_nodes), "--threads",
               str(threads), "--seed", str(seed), "--solutions", str(solutions), "--no-progress", *EXTRA]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        stats = json.loads((out / "stats.json").read_text()) if (out / "stats.json").exists() else {}
        return {"wall_s": wall, "rc": proc.returncode, "solutions": stats.get("solutions"),
                "nodes": stats.get("nodes_tested"), "digest": _digest(out) if out.exists() else None,
                "stderr_tail": proc.stderr[-300:] if proc.returncode not in (0, 1) else ""}


def _loaded(hogs: int, fn, *args) -> dict:
    stop_at = time.time() + 3600
    procs = [mp.Process(target=_hog, args=(stop_at,), daemon=True) for _ in range(hogs)]
    for p in procs:
        p.start()
    try:
        time.sleep(1.0)
        return fn(*args)
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.join()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="box-turn")
    ap.add_argument("--max-nodes", type=int, default=6000)
    ap.add_argument("--solutions", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--hogs", type=int, default=1, help="busy processes beside the loaded runs (default 1)")
    ap.add_argument("--wait-policy", nargs="*", default=[], help="OMP_WAIT_POLICY values to compare under load")
    ap.add_argument("--extra", default="", help="more synthesize arguments, e.g. '--frames 14:38'")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args(argv)
    EXTRA[:] = args.extra.split()
    rows = []
    for n in args.threads:
        alone = _run(args.scene, args.max_nodes, n, args.seed, args.solutions, {})
        busy = _loaded(args.hogs, _run, args.scene, args.max_nodes, n, args.seed, args.solutions, {})
        rows.append({"threads": n, "alone": alone, "loaded": busy})
        print(f"threads {n}: alone {alone['wall_s']:.1f} s ({alone['solutions']} sol, {alone['nodes']} nodes), "
              f"beside {args.hogs} busy process(es) {busy['wall_s']:.1f} s ({busy['solutions']} sol), "
              f"ratio {busy['wall_s'] / alone['wall_s']:.2f}, identical arrays: {alone['digest'] == busy['digest']}",
              flush=True)
    for policy in args.wait_policy:
        n = max(args.threads)
        busy = _loaded(args.hogs, _run, args.scene, args.max_nodes, n, args.seed, args.solutions,
                       {"OMP_WAIT_POLICY": policy})
        rows.append({"threads": n, "wait_policy": policy, "loaded": busy})
        print(f"threads {n}, OMP_WAIT_POLICY={policy}: beside {args.hogs} busy process(es) {busy['wall_s']:.1f} s",
              flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
