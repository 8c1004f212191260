"""One resynthesis step's time, checkout against checkout, in one run (Kry & Pai 2006; the A/B of BENCHMARKS.md).

``python scripts/bench_resynth_ab.py INFERRED_DIR CHECKOUT [CHECKOUT ...] [--alternations 5] [--dt 1/120]``

Each CHECKOUT is a source tree whose ``torchhand`` package (and its own kernels) is imported through ``PYTHONPATH``
(``.`` for the current one; an older commit: ``git worktree add /tmp/old <sha>``, then link
``/tmp/old/torchhand/kernels -> ../kernels`` and ``/tmp/old/torchhand/render -> ../render``). The checkouts run in
turn, ``--alternations`` times, each in its own process: 4 rollouts of the inferred interaction (Lemke, float64, one
thread, steps of ``--dt``), the first a warm-up; a timer around the rollout loop's step call (the same code for
every checkout, whatever its own timings record) gives each rollout's median step. Printed per checkout: the median
step of every alternation (the median of its 3 rollouts), their median, its ratio to the first checkout, and the
sum of |q| over the rollout, which shows whether the checkouts compute the same motion.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys


def one(inferred: str, dt: float) -> dict:
    """This process's measurement (run under the checkout's PYTHONPATH)."""
    import time

    import torch

    torch.set_num_threads(1)
    from torchhand.interaction import _rollout_loop as loop
    from torchhand.interaction.resynth import ResynthSettings, load_interaction, resynthesize
    from torchhand.scene import load_scene

    inter = load_interaction(os.path.join(inferred, "interaction.npz"))
    scene = load_scene(os.path.join(inferred, "scene"))
    step, walls = loop.quasi_static_step, []

    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return step(*args, **kwargs)
        finally:
            walls.append(time.perf_counter() - t)

    loop.quasi_static_step = timed
    medians = []
    for r in range(4):
        walls.clear()
        res = resynthesize(inter, scene, settings=ResynthSettings(dt=dt, solver="lemke"))
        if r:
            medians.append(1e3 * statistics.median(walls))
    return {"median_ms": statistics.median(medians), "q_abs_sum": float(abs(res.rollouts[0].q).sum())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inferred", help="output directory of `torchhand capture from-result`")
    p.add_argument("checkouts", nargs="*", help="source trees to compare (default: the current one)")
    p.add_argument("--alternations", type=int, default=5)
    p.add_argument("--dt", default="1/120", help="step, seconds (1/120)")
    p.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    num, _, den = a.dt.partition("/")
    dt = float(num) / float(den or 1)
    if a.one:
        print(json.dumps(one(a.inferred, dt)))
        return 0
    trees = [os.path.abspath(c) for c in (a.checkouts or ["."])]
    runs = {t: [] for t in trees}
    for _ in range(a.alternations):
        for t in trees:
            env = dict(os.environ, PYTHONPATH=t)
            out = subprocess.run([sys.executable, os.path.abspath(__file__), a.inferred, "--one", "--dt", a.dt],
                                 env=env, capture_output=True, text=True, check=True, cwd=t)
            runs[t].append(json.loads(out.stdout.strip().splitlines()[-1]))
    base = statistics.median(r["median_ms"] for r in runs[trees[0]])
    for t in trees:
        meds = [r["median_ms"] for r in runs[t]]
        m = statistics.median(meds)
        print(f"{t}: {' / '.join(f'{x:.2f}' for x in meds)} ms; median {m:.2f} ms, ratio {m / base:.2f}; "
              f"sum |q| {runs[t][-1]['q_abs_sum']:.12f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
