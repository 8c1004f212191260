"""Batch throughput: jobs per hour of ``torchhand batch`` on a small fixed manifest, with 1 and 2 workers, with
the tool's own choice of workers and threads, and (``--ray``) on a local Ray instance.

The manifest is six ``synthesize`` jobs (box-turn, bottle-turn, cube-turn × seeds 0 and 1, the built-in hand,
frames 0:8, a budget of 400 node tests, one solution): every job is the same work on any machine, so the rows
differ only in how they are run. Each row runs ``torchhand batch`` as a subprocess into a fresh directory
(``--repeats`` times; median and spread of the wall time) and reports jobs per hour, the speed-up over the
1-worker row measured in the same run, the median attempt time (``job_s``: synthesis, check and process start) and
a digest of every solution array: rows with the same thread count must agree (runs are deterministic given seed,
node budget and thread count).

    python scripts/bench_batch.py --json bench_batch.json [--repeats 2] [--ray]
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import machine, print_table, write_json  # noqa: E402

MANIFEST = """# scripts/bench_batch.py: six small synthesize jobs
[defaults]
method = "synthesize"
solutions = 1
max_nodes = 400
frames = "0:8"
trees = 4
candidates = 8

[[jobs]]
scenes = ["box-turn", "bottle-turn", "cube-turn"]
seeds = [0, 1]
"""


def arrays_digest(out: Path) -> str:
    """SHA-256 over every job's solution arrays, in job order (the first 12 hex digits)."""
    import numpy as np

    h = hashlib.sha256()
    for f in sorted(out.glob("jobs/*/solutions/sol_*.npz")):
        with np.load(f) as z:
            for k in sorted(z.files):
                h.update(f"{f.parent.parent.name}/{f.name}/{k}".encode() + z[k].tobytes())
    return h.hexdigest()[:12]


def run_config(manifest: Path, flags: list[str], workdir: Path) -> dict:
    """One ``torchhand batch`` run into a fresh directory: wall seconds, jobs, median attempt seconds."""
    out = Path(tempfile.mkdtemp(prefix="bench-batch-", dir=workdir)) / "out"
    cmd = [sys.executable, "-m", "torchhand.cli", "batch", str(manifest), "--out", str(out), "--no-progress", *flags]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"bench_batch: {' '.join(cmd)} exited with {proc.returncode}:\n{proc.stderr[-2000:]}")
    with open(out / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    import json

    runs = json.loads((out / "batch.json").read_text())["runs"]
    return {"wall_s": wall, "jobs": len(rows), "finished": sum(r["status"] == "finished" for r in rows),
            "job_s": statistics.median(float(r["job_s"]) for r in rows if r["job_s"]),
            "workers": runs[-1]["workers"], "threads": runs[-1]["threads"], "digest": arrays_digest(out)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=1, help="runs per row (default 1; median and spread)")
    p.add_argument("--ray", action="store_true", help="add a row on a local Ray instance (--ray auto)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    configs = [("1 worker x 1 thread", ["--workers", "1", "--threads", "1"]),
               ("1 worker x 2 threads", ["--workers", "1", "--threads", "2"]),
               ("2 workers x 1 thread", ["--workers", "2", "--threads", "1"]),
               ("tool's choice (no flags)", [])]
    if a.ray:
        configs.append(("Ray auto, tool's choice", ["--ray", "auto"]))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        manifest = Path(tmp) / "batch.toml"
        manifest.write_text(MANIFEST)
        for name, flags in configs:
            runs = [run_config(manifest, flags, Path(tmp)) for _ in range(a.repeats)]
            walls = [r["wall_s"] for r in runs]
            med = statistics.median(walls)
            rows.append({"config": name, "flags": " ".join(flags), "workers": runs[0]["workers"],
                         "threads": runs[0]["threads"], "jobs": runs[0]["jobs"], "finished": runs[0]["finished"],
                         "wall_s": med, "spread_s": max(walls) - min(walls), "repeats": a.repeats,
                         "jobs_per_hour": runs[0]["jobs"] * 3600 / med,
                         "job_s": statistics.median(r["job_s"] for r in runs),
                         "arrays": ",".join(sorted({r["digest"] for r in runs}))})
    base = rows[0]["jobs_per_hour"]
    for r in rows:
        r["vs_1_worker"] = r["jobs_per_hour"] / base
    info = {"machine": machine(), "usable_cpus": len(os.sched_getaffinity(0)), "command": " ".join(sys.argv),
            "manifest": MANIFEST, "rows": rows}
    print(f"machine: {info['machine']}, usable CPUs {info['usable_cpus']}")
    print_table(rows, ["config", "workers", "threads", "jobs", "finished", "wall_s", "spread_s", "jobs_per_hour",
                       "vs_1_worker", "job_s", "arrays"])
    if a.json:
        write_json(a.json, info)
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
