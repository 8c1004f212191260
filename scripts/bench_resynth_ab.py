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
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import alternate, print_ratios  # noqa: E402


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
    runs = alternate(__file__, [a.inferred, "--dt", a.dt], a.checkouts or ["."], a.alternations)
    print_ratios(runs, "median_ms", "ms", extra=lambda r: f"; sum |q| {r['q_abs_sum']:.12f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
