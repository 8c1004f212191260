"""What the portable numeric profile costs (docs/synthesis.md, "The same arithmetic on any x86-64 CPU").

Each case runs `torchhand` in a fresh process (the profile is read when torch and NumPy load) under
`--numerics portable` and `--numerics native`, the two modes interleaved run by run so that a change of load on a
shared machine hits both alike, and reads its speed from the result's stats.json:

  search       `synthesize box-turn --max-nodes N --solutions 1000 --no-reconstruct`: node tests per second of
               the search (stats `nodes_per_second`; search time only)
  finalize     `synthesize box-turn --solutions 3`: seconds of finishing the paths (spacetime reconstruction and the
               exact re-check, stats `timings_s.finalize_s`) per path found (the two modes find different paths)
  manipulate   `manipulate liu-drag`: frames per second of the whole loop (stats `frames_per_second`)

Median of --repeat runs per mode; the table gives portable / native.

    python scripts/bench_numerics.py [--repeat 3] [--nodes 3000] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

CASES = {
    "search": (["synthesize", "box-turn", "--solutions", "1000", "--no-reconstruct", "--seed", "0"],
               lambda s: s["nodes_per_second"], "node tests/s"),
    "finalize": (["synthesize", "box-turn", "--solutions", "3", "--max-nodes", "60000", "--seed", "0"],
                 lambda s: s["timings_s"]["finalize_s"] / max(s["paths_found"], 1), "s per path"),
    "manipulate": (["manipulate", "liu-drag"], lambda s: s["frames_per_second"], "frames/s"),
}


def run_case(case: str, mode: str, nodes: int, workdir: Path, k: int) -> float:
    args, read, _ = CASES[case]
    out = workdir / f"{case}-{mode}-{k}"
    extra = ["--max-nodes", str(nodes)] if case == "search" else []
    cmd = [sys.executable, "-m", "torchhand.cli", "--numerics", mode, *args, *extra, "--out", str(out),
           "--threads", "1", "--no-progress"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if run.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} exited {run.returncode}:\n{run.stderr[-2000:]}")
    stats = json.loads((out / "stats.json").read_text())
    assert stats["numerics"]["mode"] == mode or mode == "native", stats["numerics"]
    return float(read(stats))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--nodes", type=int, default=3000, help="node budget of the search case (default 3000)")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases.split(","):
            samples = {"portable": [], "native": []}
            for k in range(a.repeat):
                for mode in ("portable", "native") if k % 2 == 0 else ("native", "portable"):
                    samples[mode].append(run_case(case, mode, a.nodes, Path(tmp), k))
                    print(f"{case:10s} {mode:8s} run {k}: {samples[mode][-1]:.4g}", file=sys.stderr, flush=True)
            med = {m: statistics.median(v) for m, v in samples.items()}
            rows[case] = {"unit": CASES[case][2], **med, "samples": samples,
                          "portable_over_native": med["portable"] / med["native"]}
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; one thread")
    print(f"{'case':12s}{'unit':>16s}{'portable':>12s}{'native':>12s}{'portable/native':>18s}")
    for case, r in rows.items():
        print(f"{case:12s}{r['unit']:>16s}{r['portable']:12.4g}{r['native']:12.4g}{r['portable_over_native']:18.3f}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
