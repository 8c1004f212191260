"""Per-step time of one quasi-static resynthesis rollout (Kry & Pai 2006) with a whole hand, in three contact set-ups.

``python scripts/bench_resynth.py INFERRED_DIR [--repeats 3] [--threads 1] [--json OUT]``

INFERRED_DIR is the output of ``torchhand capture from-result`` (its ``interaction.npz`` and ``scene/``), e.g. the
``inferred`` folder that ``scripts/demo_inferred.py`` writes. Each row runs ``resynthesize`` on that interaction and
scene (Lemke, float64, one rollout) and reports the median of the per-step times over ``--repeats`` runs:

- the default: link capsules against the exact mesh, finger-finger contact slots;
- the exact mesh without finger-finger slots;
- the paper's set-up: an SDF grid (1 mm) and no finger-finger slots.

Real time at 120 Hz is <= 8.3 ms per step.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import machine, print_table, write_json  # noqa: E402

from torchhand.interaction.resynth import ResynthSettings, load_interaction, resynthesize  # noqa: E402
from torchhand.scene import load_scene  # noqa: E402

CASES = (("exact mesh + finger-finger slots (default)", {}),
         ("exact mesh, no finger-finger slots", {"self_contacts": False}),
         ("SDF 1 mm, no finger-finger slots", {"object_contacts": "sdf", "self_contacts": False}))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inferred", help="output directory of `torchhand capture from-result`")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    inter = load_interaction(os.path.join(a.inferred, "interaction.npz"))
    scene = load_scene(os.path.join(a.inferred, "scene"))
    rows = []
    for name, options in CASES:
        times, res = [], None
        for _ in range(a.repeats):
            res = resynthesize(inter, scene, settings=ResynthSettings(**options))
            times.append(res.timings["per_step_ms"])
        r = res.rollouts[0]
        rows.append({"contacts": name, "steps": int(r.q.shape[0]), "ms_per_step": statistics.median(times),
                     "spread_ms": max(times) - min(times), "x_real_time_120hz": (1e3 / 120) / statistics.median(times),
                     "status": r.status.name})
    info = machine()
    print(f"machine: {info}")
    print_table(rows, ["contacts", "steps", "ms_per_step", "spread_ms", "x_real_time_120hz", "status"])
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
